#!/usr/bin/env bash
# Provision the Python environment of the other-language client test
# (runner/tests/python_client.rs runs tests/python/decode_status.py with it): a venv under
# target/py-client with eclipse-zenoh pinned to the Rust side's Zenoh release, from PyPI.
# Idempotent: a second run checks the installed version and exits.
set -euo pipefail

ZENOH_PY_VERSION=1.10.2

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="${root}/target/py-client"
py="${venv}/bin/python"

die() { echo "setup-python-client: error: $*" >&2; exit 1; }

installed() {
    [[ -x "${py}" ]] && "${py}" -c "import importlib.metadata as m, zenoh; assert m.version('eclipse-zenoh') == '${ZENOH_PY_VERSION}'" 2>/dev/null
}

if installed; then
    echo "setup-python-client: eclipse-zenoh ${ZENOH_PY_VERSION} already in ${venv}"
    exit 0
fi
command -v python3 >/dev/null || die "python3 not found (the Python client test needs python3 with the venv module)"
python3 -m venv "${venv}" || die "python3 -m venv ${venv} failed (Debian: apt-get install python3-venv)"
"${venv}/bin/pip" install --quiet --disable-pip-version-check "eclipse-zenoh==${ZENOH_PY_VERSION}" \
    || die "pip could not install eclipse-zenoh==${ZENOH_PY_VERSION} (is PyPI reachable?)"
installed || die "eclipse-zenoh installed but 'import zenoh' fails"
echo "setup-python-client: eclipse-zenoh ${ZENOH_PY_VERSION} installed in ${venv}"
