#!/usr/bin/env bash
# What the test hosts (scripts/testhosts.sh) need: iproute2 and nftables (and openssl, which the
# access-control tests' scripts/make-test-certs.sh uses), installed from Debian's
# packages when missing and this is root on a Debian machine (CI runs as root). Elsewhere it
# says what is missing and carries on: the tests that would use test hosts then say so and run
# on loopback.
set -euo pipefail
missing=()
command -v ip >/dev/null || missing+=(iproute2)
command -v nft >/dev/null || missing+=(nftables)
command -v openssl >/dev/null || missing+=(openssl)
[[ ${#missing[@]} -eq 0 ]] && exit 0
if [[ $(id -u) -eq 0 ]] && command -v apt-get >/dev/null; then
  echo "setup-testhosts: installing ${missing[*]}" >&2
  timeout 600 apt-get install -y --no-install-recommends "${missing[@]}" >/dev/null 2>&1 \
    || { timeout 300 apt-get update >/dev/null 2>&1 && timeout 600 apt-get install -y --no-install-recommends "${missing[@]}" >/dev/null 2>&1; } \
    || echo "setup-testhosts: could not install ${missing[*]}: the test-host tests will run on loopback" >&2
else
  echo "setup-testhosts: ${missing[*]} missing and not root: the test-host tests will run on loopback" >&2
fi
