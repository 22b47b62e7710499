#!/usr/bin/env bash
# Provision libmujoco 3.17.0 for mujoco-rs (how it is found: docs/testing.md).
#
# MuJoCo's own release host cannot be reached from our machines, so the library comes from
# the PyPI wheel `mujoco==3.17.0`, which ships `mujoco/libmujoco.so.3.17.0` and the C headers
# and needs no Python at run time. This script downloads that wheel (pinned platform and
# Python tag, so the bytes are always the same), checks its sha256, unpacks the library and
# headers into `third_party/mujoco/` (git-ignored) and adds the `libmujoco.so` link that
# the linker looks for. `.cargo/config.toml` points MUJOCO_DYNAMIC_LINK_DIR there and gives
# every binary an rpath, so nobody has to export anything.
#
# Idempotent: a second run checks the installed library and exits.
set -euo pipefail

MUJOCO_VERSION=3.17.0
WHEEL="mujoco-${MUJOCO_VERSION}-cp311-cp311-manylinux_2_27_x86_64.manylinux_2_28_x86_64.whl"
WHEEL_SHA256=d66928d86a2d1b601bbaa4dc11db50214d17d5301bb8afd84721313b67ff0874

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
dest="${root}/third_party/mujoco"
lib="${dest}/lib/libmujoco.so.${MUJOCO_VERSION}"

die() { echo "setup-mujoco: error: $*" >&2; exit 1; }

if [[ -f "${lib}" && -L "${dest}/lib/libmujoco.so" && -f "${dest}/include/mujoco/mujoco.h" \
      && -f "${dest}/VERSION" && "$(cat "${dest}/VERSION")" == "${MUJOCO_VERSION} ${WHEEL_SHA256}" ]]; then
    echo "setup-mujoco: MuJoCo ${MUJOCO_VERSION} already in ${dest}"
    exit 0
fi

[[ "$(uname -s)" == Linux && "$(uname -m)" == x86_64 ]] \
    || die "only linux x86_64 is provisioned automatically (this is $(uname -s) $(uname -m)); set MUJOCO_DYNAMIC_LINK_DIR by hand"
command -v python3 >/dev/null 2>&1 \
    || die "python3 is needed to download the MuJoCo wheel from PyPI (apt-get install python3 python3-pip)"
python3 -m pip --version >/dev/null 2>&1 \
    || die "pip is needed to download the MuJoCo wheel from PyPI (apt-get install python3-pip)"

work="$(mktemp -d)"
trap 'rm -rf "${work}"' EXIT

echo "setup-mujoco: downloading ${WHEEL} from PyPI"
python3 -m pip download --quiet --no-deps --only-binary=:all: \
    --python-version 3.11 --implementation cp --abi cp311 \
    --platform manylinux_2_28_x86_64 \
    --dest "${work}" "mujoco==${MUJOCO_VERSION}" \
    || die "pip could not download mujoco==${MUJOCO_VERSION} (is PyPI reachable?)"
[[ -f "${work}/${WHEEL}" ]] || die "pip did not produce ${WHEEL}: got $(ls "${work}")"

got="$(sha256sum "${work}/${WHEEL}" | cut -d' ' -f1)"
[[ "${got}" == "${WHEEL_SHA256}" ]] \
    || die "sha256 mismatch for ${WHEEL}: expected ${WHEEL_SHA256}, got ${got}"

python3 - "${work}/${WHEEL}" "${work}/x" <<'PY'
import sys, zipfile
wheel, out = sys.argv[1], sys.argv[2]
with zipfile.ZipFile(wheel) as z:
    members = [n for n in z.namelist()
               if n.startswith("mujoco/include/") or n.startswith("mujoco/libmujoco.so")]
    z.extractall(out, members)
PY

rm -rf "${dest}"
mkdir -p "${dest}/lib"
mv "${work}/x/mujoco/include" "${dest}/include"
mv "${work}/x/mujoco/libmujoco.so.${MUJOCO_VERSION}" "${lib}"
ln -s "libmujoco.so.${MUJOCO_VERSION}" "${dest}/lib/libmujoco.so"
echo "${MUJOCO_VERSION} ${WHEEL_SHA256}" > "${dest}/VERSION"
echo "setup-mujoco: MuJoCo ${MUJOCO_VERSION} installed in ${dest}"
