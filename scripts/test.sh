#!/usr/bin/env bash
# Runs every climbsim test on a fresh machine: makes .venv with the pinned official DynamixelSDK
# (tests/sdk/requirements.txt), then `cargo test` (unit, golden-vector, property, dynamixel2 and
# official-SDK tests). Extra arguments go to `cargo test`.
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$repo"

venv="$repo/.venv"
stamp="$venv/.requirements.sha256"
want="$(sha256sum tests/sdk/requirements.txt | cut -d' ' -f1)"
if [[ ! -x "$venv/bin/python" || "$(cat "$stamp" 2>/dev/null)" != "$want" ]]; then
    echo "==> creating $venv with tests/sdk/requirements.txt"
    python3 -m venv "$venv"
    "$venv/bin/python" -m pip install --quiet --disable-pip-version-check -r tests/sdk/requirements.txt
    echo "$want" > "$stamp"
fi
export CLIMBSIM_PYTHON="$venv/bin/python"

echo "==> cargo test"
cargo test --locked "$@"
