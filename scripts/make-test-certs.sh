#!/usr/bin/env bash
# Make a TEST certificate authority and one certificate per team identity, for Zenoh's mutual
# TLS and access control (README "Access control (mutual TLS and ACL)").
#
#   scripts/make-test-certs.sh [--san SAN]... [--ca CADIR] [--team TEAM] DIR [ROBOT...]
#   scripts/make-test-certs.sh [--san SAN]... --router DIR
#
# Writes into DIR (created if missing):
#   ca.pem, ca.key                 the test CA (EC P-256, 10 years)
#   IDENTITY.pem, IDENTITY.key     one per identity: coordinator, each ROBOT (default: r1 r2),
#                                  sim-bridge, runner (the scenario driver), tool (read-only);
#                                  the certificate's common name (CN) is the identity, which is
#                                  what the access-control rules name (protocol::access)
# Every certificate is for both ends of a link (extendedKeyUsage serverAuth and clientAuth: a
# Zenoh peer listens and connects) and names 127.0.0.1 and localhost (subjectAltName); add
# other addresses with --san, e.g. --san IP:10.77.1.2 --san DNS:robot1.lan (the test hosts'
# addresses, a robot's LAN name). With --ca CADIR the identities are signed by the CA already
# in CADIR (ca.pem, ca.key): DIR gets a copy of ca.pem, never the key (team run --hosts --tls
# issues a run's certificates this way).
#
# A site (several teams on one Zenoh router, docs/realtime.md "A site"): --router makes the
# site's CA and the router's certificate alone (router.pem, CN=router); --team TEAM names
# every identity's certificate IDENTITY.TEAM (e.g. r1.alpha), the name the router's access
# control gives it, the files still IDENTITY.pem. Sign each team's folder with the site's CA:
#   scripts/make-test-certs.sh --router site
#   scripts/make-test-certs.sh --ca site --team alpha site/alpha r1 r2
#
# Idempotent: an existing CA is kept, and an identity whose certificate exists and verifies
# against that CA is kept; missing ones are made. Remove DIR to start over.
#
# These are test credentials: keys are written unencrypted (mode 600). An operator replaces
# them with certificates from the site's own CA, with the same common names.
set -euo pipefail

die() { echo "make-test-certs: error: $*" >&2; exit 1; }
usage() { awk 'NR > 1 && !/^#/ { exit } NR > 1' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//' >&2; exit 2; }

extra_sans=()
ca_dir=""
team=""
router=0
while [[ $# -gt 0 ]]; do
    case "$1" in
        --ca) [[ $# -ge 2 ]] || die "--ca needs a folder with ca.pem and ca.key"
              ca_dir="$2"; shift 2 ;;
        --san) [[ $# -ge 2 ]] || die "--san needs a value (IP:ADDR or DNS:NAME)"
               [[ "$2" =~ ^(IP|DNS):[A-Za-z0-9.:-]+$ ]] || die "--san $2: expected IP:ADDR or DNS:NAME"
               extra_sans+=("$2"); shift 2 ;;
        --team) [[ $# -ge 2 ]] || die "--team needs a team name"
                [[ "$2" =~ ^[A-Za-z0-9_-]{1,64}$ ]] || die "team name '$2' is not [A-Za-z0-9_-]{1,64} (protocol::validate_id)"
                team="$2"; shift 2 ;;
        --router) router=1; shift ;;
        -h|--help) usage ;;
        --) shift; break ;;
        -*) die "unknown option $1 (see --help)" ;;
        *) break ;;
    esac
done
[[ $# -ge 1 ]] || usage
dir="$1"; shift
robots=("$@")
if [[ $router -eq 1 ]]; then
    [[ ${#robots[@]} -eq 0 && -z "$team" ]] || die "--router makes the router's certificate alone: no robots, no --team"
fi
[[ ${#robots[@]} -gt 0 ]] || robots=(r1 r2)

command -v openssl >/dev/null 2>&1 || die "openssl is needed (apt-get install openssl)"
reserved=(coordinator sim-bridge runner tool ca)
for r in "${robots[@]}"; do
    [[ "$r" =~ ^[A-Za-z0-9_-]{1,64}$ ]] || die "robot id '$r' is not [A-Za-z0-9_-]{1,64} (protocol::validate_id)"
    for x in "${reserved[@]}"; do [[ "$r" != "$x" ]] || die "robot id '$r' is reserved for another identity"; done
done

mkdir -p "$dir" || die "cannot create $dir"
umask 077
days=3650
san="IP:127.0.0.1,DNS:localhost"
for s in "${extra_sans[@]+"${extra_sans[@]}"}"; do san="${san},${s}"; done

ca_pem="$dir/ca.pem"
ca_key="$dir/ca.key"
if [[ -n "$ca_dir" ]]; then
    [[ -f "$ca_dir/ca.pem" && -f "$ca_dir/ca.key" ]] || die "--ca $ca_dir: no ca.pem and ca.key there (make them with $0 $ca_dir)"
    [[ "$(cd "$ca_dir" && pwd -P)" != "$(cd "$dir" && pwd -P)" ]] || die "--ca $ca_dir is DIR itself"
    cp "$ca_dir/ca.pem" "$dir/ca.pem" || die "cannot copy $ca_dir/ca.pem into $dir"
    ca_key="$ca_dir/ca.key"
    echo "make-test-certs: signing with the CA of $ca_dir"
elif [[ -f "$dir/ca.pem" && -f "$dir/ca.key" ]]; then
    echo "make-test-certs: keeping the CA in $dir/ca.pem"
else
    openssl req -x509 -new -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes \
        -keyout "$dir/ca.key" -out "$dir/ca.pem" -days "$days" -subj "/CN=team test CA" \
        -addext "basicConstraints=critical,CA:TRUE" \
        -addext "keyUsage=critical,keyCertSign,cRLSign" 2>/dev/null \
        || die "openssl could not make the CA in $dir"
    echo "make-test-certs: made the CA $dir/ca.pem"
fi

# The certificate's common name: the identity, or IDENTITY.TEAM on a site.
common_name() {
    if [[ -n "$team" && "$1" != router ]]; then echo "$1.$team"; else echo "$1"; fi
}

make_identity() {
    local id="$1" tmp cn
    cn="$(common_name "$id")"
    if [[ -f "$dir/$id.pem" && -f "$dir/$id.key" ]] \
        && openssl verify -CAfile "$dir/ca.pem" "$dir/$id.pem" >/dev/null 2>&1 \
        && [[ "$(openssl x509 -noout -subject -nameopt multiline -in "$dir/$id.pem" | sed -n 's/^ *commonName *= *//p')" == "$cn" ]]; then
        echo "make-test-certs: keeping $dir/$id.pem"
        return
    fi
    tmp="$(mktemp -d)"
    openssl req -new -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes \
        -keyout "$tmp/key.pem" -out "$tmp/req.csr" -subj "/CN=$cn" 2>/dev/null \
        || { rm -rf "$tmp"; die "openssl could not make a key for $id"; }
    cat > "$tmp/ext.cnf" <<EOF
basicConstraints=critical,CA:FALSE
keyUsage=critical,digitalSignature,keyEncipherment
extendedKeyUsage=serverAuth,clientAuth
subjectAltName=$san
EOF
    openssl x509 -req -in "$tmp/req.csr" -CA "$ca_pem" -CAkey "$ca_key" -CAserial "$dir/ca.srl" -CAcreateserial \
        -out "$tmp/cert.pem" -days "$days" -extfile "$tmp/ext.cnf" 2>/dev/null \
        || { rm -rf "$tmp"; die "openssl could not sign the certificate of $id"; }
    mv "$tmp/key.pem" "$dir/$id.key"
    mv "$tmp/cert.pem" "$dir/$id.pem"
    chmod 644 "$dir/$id.pem"
    rm -rf "$tmp"
    echo "make-test-certs: made $dir/$id.pem (CN=$cn, $san)"
}

chmod 644 "$dir/ca.pem"
if [[ $router -eq 1 ]]; then
    make_identity router
else
    for id in coordinator "${robots[@]}" sim-bridge runner tool; do
        make_identity "$id"
    done
fi
rm -f "$dir/ca.srl"
