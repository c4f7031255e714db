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
