#!/usr/bin/env bash
# climbsim as a user outside its checkout gets it, run by scripts/test.sh after the test build:
#   1. the wheel, built with maturin from the test build's target folder (the dev profile and
#      scripts/test.sh's settings, not stripped: nothing compiles again, the binary is packed), installed into
#      a fresh venv with what the generated controller needs;
#   2. in an empty folder outside the checkout: `climbsim init`, the generated pytest suite,
#      `climbsim check scenarios/ --junit`, `python -m climbsim`; then the Python API's and the
#      pytest plugin's own tests (tests/python/);
#   3. `cargo install --path . --root DIR` (--debug and the same target folder, for the same
#      reason) and the installed binary checks the generated scenario from an empty folder.
# Needs .venv (maturin, from tests/sdk/requirements.txt) and the build `cargo test` made.
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
target="${CARGO_TARGET_DIR:-$repo/target}"
work="$(mktemp -d "${TMPDIR:-/tmp}/climbsim-outside.XXXXXX")"
trap 'rm -rf "$work"' EXIT
source "$repo/scripts/fresh-build.sh"

step() { echo "==> $*"; }

step "maturin build (the wheel, from $target)"
started=$SECONDS
# --strip false: maturin strips by passing `-C strip=symbols` to rustc, which would link the
# binary again under another name (a minute on 2 cores) rather than pack the one cargo test made.
(cd "$repo" && "$repo/.venv/bin/maturin" build --locked --profile dev --strip false --target-dir "$target" "${fresh_build_config[@]}" --out "$work/wheels" --quiet)
wheel="$(ls "$work"/wheels/climbsim-*.whl)"
echo "    $(basename "$wheel"), $(du -h "$wheel" | cut -f1), built in $((SECONDS - started)) s"

step "pip install the wheel into a fresh venv"
python3 -m venv "$work/venv"
# The generated controller's and tests' packages, at the versions climbsim's own tests pin.
"$work/venv/bin/pip" install --quiet --disable-pip-version-check "$wheel" \
    "$(grep '^dynamixel-sdk==' "$repo/tests/sdk/requirements.txt")" \
    "$(grep '^pyserial==' "$repo/tests/sdk/requirements.txt")" \
    "$(grep '^pytest==' "$repo/tests/sdk/requirements.txt")"
# As an activated venv would have it: its climbsim and python3 first on PATH, nothing of the
# checkout's (CLIMBSIM_* variables would point into it).
user_env=(env -u CLIMBSIM_ROBOT -u CLIMBSIM_PYTHON -u CLIMBSIM_BINARY -u VIRTUAL_ENV "PATH=$work/venv/bin:/usr/local/bin:/usr/bin:/bin")

step "climbsim init, pytest and climbsim check in an empty folder"
mkdir "$work/empty"
cd "$work/empty"
"${user_env[@]}" climbsim init my-controller
cd my-controller
"${user_env[@]}" pytest -q -p no:cacheprovider
"${user_env[@]}" climbsim check scenarios/ --junit results/junit.xml --out results/check
grep -q 'tests="1" failures="0" errors="0"' results/junit.xml
"${user_env[@]}" python -m climbsim --version

step "the Python API and the pytest plugin (tests/python/)"
cp -r "$repo/tests/python" "$work/api-tests"
cd "$work/api-tests"
"${user_env[@]}" pytest -q -p no:cacheprovider test_api.py

step "cargo install --path . --root DIR, and the installed binary from an empty folder"
(cd "$repo" && cargo install --quiet --locked --debug --path . --root "$work/cargo-root" --target-dir "$target" "${fresh_build_config[@]}")
mkdir "$work/empty-2"
cd "$work/empty-2"
"$work/cargo-root/bin/climbsim" init . > /dev/null
# The controller runs on the venv's SDK; the binary is the one cargo installed.
env -u CLIMBSIM_ROBOT -u CLIMBSIM_PYTHON "PATH=$work/venv/bin:/usr/bin:/bin" "$work/cargo-root/bin/climbsim" check scenarios/line-follow.toml --out results/check
