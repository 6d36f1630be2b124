# Sourced by the GPU checks: `step SECONDS NAME COMMAND...` runs one step under its own time limit;
# its whole log (carriage returns made line breaks) goes to $out/gpu_check.log, its last lines to
# the console. Needs $work (a scratch folder) and $out set by the caller.
step() {
    local limit=$1 name=$2
    shift 2
    local began=$SECONDS
    echo "== $name"
    timeout "$limit" "$@" >"$work/$name.log" 2>&1
    local rc=$?
    tr '\r' '\n' <"$work/$name.log" | tail -n "${STEP_TAIL_LINES:-15}"
    echo "== $name: exit $rc, $((SECONDS - began)) s"
    { echo "== $name: exit $rc, $((SECONDS - began)) s"; tr '\r' '\n' <"$work/$name.log"; } >>"$out/gpu_check.log"
}
