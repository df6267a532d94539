#!/bin/sh
# Checks what `make` needs before it starts installing, and names what is missing (run by the Makefile).
#   tools/prereqs.sh python PYTHON   the interpreter the venv is made with: the version pyproject.toml asks for, venv
#   tools/prereqs.sh node [--quiet]  Node.js >= 18 and npm (MQTT.js for the dashboard, Node-RED 4 for the tests)
#   tools/prereqs.sh build           gcc, g++, make and cmake (the simulator's interface package: tools/interfaces/)
# Exit 0 when all is there; otherwise a message on stderr that names the missing piece and how to get it, exit 1.
set -u
NODE_MIN=18

need_node() {
    missing=""
    command -v node >/dev/null 2>&1 || missing="Node.js (node)"
    command -v npm >/dev/null 2>&1 || missing="${missing:+$missing and }npm"
    if [ -z "$missing" ]; then
        major=$(node -p 'process.versions.node.split(".")[0]' 2>/dev/null || echo 0)
        [ "$major" -ge "$NODE_MIN" ] 2>/dev/null && return 0
        missing="Node.js >= $NODE_MIN (node is $(node --version 2>/dev/null || echo unknown))"
    fi
    [ "${1:-}" = "--quiet" ] && return 1
    echo "missing prerequisite: $missing." >&2
    echo "  The web dashboard (make dashboard) and the tests (make test) need Node.js >= $NODE_MIN and npm for" >&2
    echo "  MQTT.js and Node-RED; make demo runs without them. On Debian/Ubuntu: sudo apt-get install nodejs npm" >&2
    return 1
}

need_python() {
    python=${1:-python3}
    if ! command -v "$python" >/dev/null 2>&1; then
        echo "missing prerequisite: $python (Python, the version pyproject.toml's requires-python names)." >&2
        echo "  On Debian/Ubuntu: sudo apt-get install python3 python3-venv; another one: make PYTHON=python3.11 ..." >&2
        return 1
    fi
    # The venv holds the bridge, whose ROS wheels name the one Python they are built for (a marker in pyproject.toml);
    # without such a marker, requires-python. Checked by the interpreter itself (no tomllib before 3.11: a regex).
    "$python" - <<'PY' || return 1
import re, sys
project = open("pyproject.toml").read()
wheels = re.search(r'"ros-jazzy-rclpy[^";]*;\s*python_version\s*==\s*\'([0-9.]+)\'', project)
spec = f"=={wheels.group(1)}" if wheels else re.search(r'requires-python\s*=\s*"([^"]*)"', project).group(1)
why = "the bridge's ROS 2 wheels in pyproject.toml" if wheels else "requires-python in pyproject.toml"
ok = True
for op, version in re.findall(r"(>=|<=|==|<|>)\s*([0-9.]+)", spec):
    want, have = tuple(int(p) for p in version.split(".")), sys.version_info[:len(version.split("."))]
    ok = ok and {">=": have >= want, "<": have < want, "<=": have <= want, ">": have > want, "==": have == want}[op]
if not ok:
    print(f"missing prerequisite: Python {spec} ({why}); {sys.executable} is "
          f"{sys.version.split()[0]}.\n  Install one (e.g. pyenv install 3.11) and run: make PYTHON=python3.11 ...",
          file=sys.stderr)
    sys.exit(1)
try:
    import ensurepip, venv  # noqa: F401  (Debian splits them into python3.X-venv)
except ImportError:
    print(f"missing prerequisite: the venv module of {sys.executable}.\n"
          f"  On Debian/Ubuntu: sudo apt-get install python3.{sys.version_info[1]}-venv", file=sys.stderr)
    sys.exit(1)
PY
}

need_build() {
    missing=""
    for tool in gcc g++ make cmake; do
        command -v "$tool" >/dev/null 2>&1 || missing="${missing:+$missing, }$tool"
    done
    [ -z "$missing" ] && return 0
    echo "missing prerequisite: $missing." >&2
    echo "  make install builds the simulator's navigation action (a ROS interface package) from the ROS wheels" >&2
    echo "  with a C compiler and cmake. On Debian/Ubuntu: sudo apt-get install build-essential cmake" >&2
    return 1
}

case "${1:-}" in
    node) need_node "${2:-}" ;;
    build) need_build ;;
    python) need_python "${2:-python3}" ;;
    *) echo "usage: tools/prereqs.sh python PYTHON | node [--quiet] | build" >&2; exit 2 ;;
esac
