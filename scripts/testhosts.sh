#!/usr/bin/env bash
# Test hosts: Linux network namespaces joined by veth pairs to one bridge, so that the team's
# components run as separate machines on one computer (root needed). The bridge, in the
# namespace this script runs in, has NET.1; host k (in the order given to `up`) has NET.(k+2)
# on its `eth0`. All traffic stays on the bridge and inside the namespaces.
#
#   testhosts.sh check                     exit 0 if namespaces, veth pairs and nft work here
#   testhosts.sh up SET NET NAME...        make hosts SET-NAME..., e.g. up th1 10.77.1 coordinator r1 r2 sim
#   testhosts.sh down SET                  remove every host of SET and its bridge
#   testhosts.sh addr SET NAME             print the host's address
#   testhosts.sh loss SET NAME PERCENT     drop PERCENT % (0-100) of the packets entering and
#                                          leaving the host's eth0, at random (nftables numgen);
#                                          0 removes the rule
#   testhosts.sh dropped SET NAME          print how many packets the loss rule dropped
#   testhosts.sh link SET NAME up|down     take the host's link up or down
#   testhosts.sh cut SET NAME PEER         reset the host's TCP connections to host PEER (ss -K:
#                                          both ends see the connection drop, as when a router
#                                          or a NIC resets); print how many were cut
#
# SET is at most 6 characters (interface names are at most 15). This kernel may have no netem:
# fixed delay cannot be added with tc, only loss and link failures.
#
# The hosts' network is a control network: TCP retransmits a lost segment after RTO_MIN
# (environment variable, default 5ms) instead of Linux's 200 ms, set on every route of the set
# (`ip route ... rto_min`). A robot LAN that carries the team over TCP needs the same setting:
# with 200 ms, one lost packet stalls a link for 50 to 600 control ticks at 250 Hz to 1 kHz.
# RTO_MIN=200ms gives Linux's default.
set -euo pipefail

die() { echo "testhosts: $*" >&2; exit 1; }
ns() { echo "$1-$2"; }

check_set() {
  [[ "$1" =~ ^[a-z][a-z0-9]{0,5}$ ]] || die "set name '$1': 1-6 lowercase letters and digits, starting with a letter"
}

cmd_check() {
  [[ $(id -u) -eq 0 ]] || die "not root: network namespaces need root"
  command -v ip >/dev/null || die "no 'ip' (Debian package iproute2)"
  command -v nft >/dev/null || die "no 'nft' (Debian package nftables)"
  local probe="thprobe$$"
  ip netns add "$probe" 2>/dev/null || die "cannot make a network namespace here"
  local ok=1
  ip link add "thp$$a" type veth peer name "thp$$b" 2>/dev/null || ok=0
  ip link del "thp$$a" 2>/dev/null || true
  ip netns exec "$probe" nft add table inet probe 2>/dev/null || ok=0
  ip netns del "$probe"
  [[ $ok -eq 1 ]] || die "veth pairs or nftables do not work in a namespace here"
}

cmd_up() {
  local set=$1 net=$2; shift 2
  check_set "$set"
  [[ "$net" =~ ^[0-9]+\.[0-9]+\.[0-9]+$ ]] || die "network '$net': three octets, e.g. 10.77.1"
  [[ $# -ge 1 && $# -le 200 ]] || die "give 1 to 200 host names"
  local br="${set}br"
  ip link show "$br" >/dev/null 2>&1 && die "set $set exists (testhosts.sh down $set)"
  ip link add "$br" type bridge
  local rto=${RTO_MIN:-5ms}
  [[ "$rto" =~ ^[0-9]+(ms|us|s)$ ]] || die "RTO_MIN '$rto': a time such as 5ms"
  ip addr add "$net.1/24" dev "$br"
  ip link set "$br" up
  ip route replace "$net.0/24" dev "$br" proto kernel scope link src "$net.1" rto_min "$rto"
  local k=0
  for name in "$@"; do
    [[ "$name" =~ ^[A-Za-z0-9_]+$ ]] || { cmd_down "$set"; die "host name '$name': letters, digits, _"; }
    local n; n=$(ns "$set" "$name")
    ip netns add "$n"
    ip link add "${set}v$k" type veth peer name "${set}p$k"
    ip link set "${set}p$k" netns "$n"
    ip -n "$n" link set "${set}p$k" name eth0
    ip -n "$n" addr add "$net.$((k + 2))/24" dev eth0
    ip -n "$n" link set lo up
    ip -n "$n" link set eth0 up
    ip -n "$n" route replace "$net.0/24" dev eth0 proto kernel scope link src "$net.$((k + 2))" rto_min "$rto"
    ip link set "${set}v$k" master "$br" up
    k=$((k + 1))
  done
}

cmd_down() {
  local set=$1
  check_set "$set"
  for n in $(ip netns list | awk '{print $1}' | grep "^$set-" || true); do
    ip netns del "$n"
  done
  ip link del "${set}br" 2>/dev/null || true
}

cmd_addr() {
  local n; n=$(ns "$1" "$2")
  ip -n "$n" -4 -o addr show dev eth0 | awk '{print $4}' | cut -d/ -f1
}

cmd_loss() {
  local n; n=$(ns "$1" "$2") p=$3
  [[ "$p" =~ ^[0-9]+$ && $p -le 100 ]] || die "loss '$p': a whole percentage, 0-100"
  ip netns exec "$n" nft delete table inet testhosts 2>/dev/null || true
  [[ $p -eq 0 ]] && return 0
  ip netns exec "$n" nft -f - <<EOF
table inet testhosts {
  chain in { type filter hook input priority 0; iifname "eth0" numgen random mod 100 < $p counter drop; }
  chain out { type filter hook output priority 0; oifname "eth0" numgen random mod 100 < $p counter drop; }
}
EOF
}

cmd_dropped() {
  local n; n=$(ns "$1" "$2")
  ip netns exec "$n" nft list table inet testhosts 2>/dev/null | grep -o 'packets [0-9]*' | awk '{s += $2} END {print s + 0}'
}

cmd_link() {
  local n; n=$(ns "$1" "$2")
  [[ "$3" == up || "$3" == down ]] || die "link state '$3': up or down"
  ip -n "$n" link set eth0 "$3"
}

cmd_cut() {
  local n; n=$(ns "$1" "$2")
  local peer; peer=$(cmd_addr "$1" "$3")
  [[ -n "$peer" ]] || die "no host $3 in set $1"
  ip netns exec "$n" ss -tnK dst "$peer" | tail -n +2 | grep -c . || true
}

case "${1:-}" in
  check) cmd_check ;;
  up) [[ $# -ge 4 ]] || die "usage: up SET NET NAME..."; shift; cmd_up "$@" ;;
  down) [[ $# -eq 2 ]] || die "usage: down SET"; cmd_down "$2" ;;
  addr) [[ $# -eq 3 ]] || die "usage: addr SET NAME"; cmd_addr "$2" "$3" ;;
  loss) [[ $# -eq 4 ]] || die "usage: loss SET NAME PERCENT"; cmd_loss "$2" "$3" "$4" ;;
  dropped) [[ $# -eq 3 ]] || die "usage: dropped SET NAME"; cmd_dropped "$2" "$3" ;;
  link) [[ $# -eq 4 ]] || die "usage: link SET NAME up|down"; cmd_link "$2" "$3" "$4" ;;
  cut) [[ $# -eq 4 ]] || die "usage: cut SET NAME PEER"; cmd_cut "$2" "$3" "$4" ;;
  *) die "usage: testhosts.sh check | up SET NET NAME... | down SET | addr SET NAME | loss SET NAME PERCENT | dropped SET NAME | link SET NAME up|down | cut SET NAME PEER" ;;
esac
