# Sourced by tools/bootstrap.sh and tools/build_interfaces.sh (not run on its own).
# talking WHAT COMMAND...: run COMMAND, saying "$TALKING_AS: still WHAT (N s)" every 10 s while it
# runs (`pip install --quiet`, a compiler whose output goes to a log, print nothing for minutes).
# Keeps COMMAND's status; Ctrl-C stops it too.
talking() {
  local what=$1 waited=0 pid
  shift
  "$@" &
  pid=$!
  trap 'kill "$pid" 2>/dev/null; exit 130' INT TERM
  while kill -0 "$pid" 2>/dev/null; do
    sleep 1
    waited=$((waited + 1))
    if ((waited % 10 == 0)) && kill -0 "$pid" 2>/dev/null; then
      echo "$TALKING_AS: still $what ($waited s)"
    fi
  done
  trap - INT TERM
  wait "$pid"
}
