# Sourced by the scripts that train in a lent window (scripts/gpu-*): a command run within what is
# left of SECONDS_LEFT, counted from the sourcing script's start (bash's SECONDS).
#
#   within_budget LABEL COMMAND [ARG...]
#
# Without SECONDS_LEFT the command runs unbounded.  With it, nothing runs once the time is spent,
# and the command is interrupted (SIGINT, then killed 30 s later) at the limit; a stop at the limit
# counts as success, since a training's kept steps are whole.  Prints LABEL's end time and status.
within_budget() {
    local label=$1 limit=() status=0 left
    shift
    if [ -n "${SECONDS_LEFT:-}" ]; then
        left=$((SECONDS_LEFT - SECONDS))
        [ "$left" -gt 0 ] || { echo "$label: no time left"; return 0; }
        limit=(timeout -s INT -k 30 "$left")
    fi
    "${limit[@]}" "$@" || status=$?
    echo "$label: until $SECONDS s (exit status $status)"
    [ "$status" = 0 ] || [ "$status" = 124 ] || [ "$status" = 130 ] || [ "$status" = 137 ]
}
