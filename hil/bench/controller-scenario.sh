# Sourced by the bench scripts: `controller_scenario FILE DURATION_S COMMAND...` writes a bare
# scenario (flat floor, a straight line) whose external controller is COMMAND and ends by itself.
controller_scenario() {
    local file="$1" duration="$2"
    shift 2
    local command="" part
    for part in "$@"; do command+="${command:+, }\"$part\""; done
    cat > "$file" <<TOML
[world]
seed = 1
duration_s = $duration
[terrain]
kind = "flat"
size_m = 4.0
[line]
points = [[-0.5, 0.0], [1.5, 0.0]]
[start]
x_m = 0.5
[controller]
kind = "external"
command = [$command]
ends_by_itself = true
TOML
}

# Sourced too: `climbsim_not_stale BINARY` fails, saying so, when BINARY is this checkout's own
# build (under its target/) and older than a source it is built from: a bench would measure the
# build before a change (`cargo build --release --examples` builds no binary). A build of
# another checkout (the build before, for a comparison) is taken as it is.
climbsim_not_stale() {
    local binary repo
    binary="$(realpath "$1")"
    repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
    [[ "$binary" == "$repo/target/"* ]] || return 0
    local newer
    newer="$(find "$repo/src" "$repo/shim/src" "$repo/build.rs" "$repo/Cargo.toml" -newer "$binary" -type f -print -quit)"
    if [[ -n "$newer" ]]; then
        echo "error: $1 is older than $newer: rebuild it (cargo build --release, or cargo build)" >&2
        return 1
    fi
}
