#!/usr/bin/env bash
# Install roslink-mqtt's systemd services on a Debian/Ubuntu robot or server: the system user, the venv, the
# configuration directory and the units. Idempotent: run it again to upgrade; it keeps your robots.yaml and
# bridge.env and replaces the units (put local changes in drop-ins: systemctl edit roslink-mqtt-bridge).
set -euo pipefail
umask 022

usage() {
    cat <<'USAGE'
usage: deploy/install.sh [options] bridge|broker...

  bridge              the robot side: roslink-mqtt[bridge] (ROS 2 Jazzy wheels), roslink-mqtt-bridge.service,
                      /etc/roslink-mqtt/bridge.env
  broker              the embedded broker: roslink-mqtt[broker], roslink-mqtt-broker.service

options:
  --prefix DIR        where the venv goes: DIR/.venv (default /opt/roslink-mqtt)
  --bridge-user NAME  the user the bridge runs as (default roslink). Give the user your robot's ROS nodes run
                      as: Fast DDS's shared memory does not connect processes of different users.
  --config FILE       the configuration to install as /etc/roslink-mqtt/robots.yaml: for the broker your fleet
                      file, for a robot its own file from `roslink-mqtt fleet split` (no password hashes).
                      Needed unless one is there already; never the demo fleet (its passwords are public)
  --python PATH       a Python 3.11 outside /home and /root (default: python3.11, then python3)
  --from-pypi         install roslink-mqtt from the package index instead of this checkout
  --dry-run           print what would be done; change nothing (root not needed)
  -h, --help          this text

It creates the system group and user roslink (useradd --system), PREFIX/.venv, /etc/roslink-mqtt/ (root:roslink,
750) with robots.yaml (--config FILE; an existing one is kept without it; 640) and, for the bridge,
bridge.env (600); it copies the units to /etc/systemd/system/ and runs systemctl daemon-reload.
USAGE
}

PREFIX=/opt/roslink-mqtt
BRIDGE_USER=roslink
PYTHON=
CONFIG=
FROM_PYPI=0
DRY_RUN=0
COMPONENTS=()
SRC=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
ETC=/etc/roslink-mqtt
UNIT_DIR=/etc/systemd/system

die() { echo "install.sh: $*" >&2; exit 2; }

while [ $# -gt 0 ]; do
    case $1 in
        --prefix) [ $# -ge 2 ] || die "--prefix needs a directory"; PREFIX=$2; shift 2 ;;
        --prefix=*) PREFIX=${1#*=}; shift ;;
        --bridge-user) [ $# -ge 2 ] || die "--bridge-user needs a name"; BRIDGE_USER=$2; shift 2 ;;
        --bridge-user=*) BRIDGE_USER=${1#*=}; shift ;;
        --config) [ $# -ge 2 ] || die "--config needs a file"; CONFIG=$2; shift 2 ;;
        --config=*) CONFIG=${1#*=}; shift ;;
        --python) [ $# -ge 2 ] || die "--python needs a path"; PYTHON=$2; shift 2 ;;
        --python=*) PYTHON=${1#*=}; shift ;;
        --from-pypi) FROM_PYPI=1; shift ;;
        --dry-run) DRY_RUN=1; shift ;;
        -h|--help) usage; exit 0 ;;
        bridge|broker) COMPONENTS+=("$1"); shift ;;
        *) usage >&2; die "unknown argument: $1" ;;
    esac
done
[ ${#COMPONENTS[@]} -gt 0 ] || { usage >&2; die "say what to install: bridge, broker or both"; }
want() { [[ " ${COMPONENTS[*]} " == *" $1 "* ]]; }
[[ $PREFIX =~ ^/[A-Za-z0-9._/-]+$ ]] || die "--prefix must be an absolute path of letters, digits, . _ - /: $PREFIX"
PREFIX=${PREFIX%/}
[[ $BRIDGE_USER =~ ^[a-z_][a-z0-9_-]*$ ]] || die "--bridge-user: not a user name: $BRIDGE_USER"
case $PREFIX in /home|/home/*|/root|/root/*|/run/user/*|/tmp/*) die "--prefix $PREFIX: the units' ProtectHome/PrivateTmp hide it" ;; esac
[ -f "$SRC/pyproject.toml" ] && [ -f "$SRC/bridge/roslink-mqtt-bridge.service" ] \
    || die "run me from a roslink-mqtt checkout ($SRC has no pyproject.toml and units)"
# The configuration: never the demo fleet, whose passwords are published (README).
if [ -n "$CONFIG" ]; then
    [ -f "$CONFIG" ] || die "--config $CONFIG: no such file"
    cmp -s "$CONFIG" "$SRC/config/robots.yaml" && die "--config $CONFIG is the demo fleet, whose passwords are" \
        "public: write your own (docs/config.md; roslink-mqtt passwd makes the hashes)"
elif [ ! -e "$ETC/robots.yaml" ]; then
    die "no configuration: pass --config FILE (the broker: your fleet file; a robot: its file from" \
        "\`roslink-mqtt fleet split\`). install.sh never installs the demo fleet: its passwords are public"
fi
if [ "$DRY_RUN" = 0 ] && [ "$(id -u)" != 0 ]; then die "needs root (or --dry-run)"; fi

# Every change goes through run: printed, and executed unless --dry-run.
run() {
    printf '+'; printf ' %q' "$@"; printf '\n'
    if [ "$DRY_RUN" = 0 ]; then "$@"; fi
}
note() { echo "# $*"; }

# A rendered copy of a unit or env file: the prefix substituted, and the bridge's user in the bridge's unit.
render() {  # render SOURCE
    local user_rule=""
    [ "$(basename "$1")" = roslink-mqtt-bridge.service ] && user_rule="s|^User=roslink\$|User=$BRIDGE_USER|"
    sed -e "s|/opt/roslink-mqtt|$PREFIX|g" ${user_rule:+-e "$user_rule"} "$1"
}
install_rendered() {  # install_rendered SOURCE MODE OWNER GROUP DEST
    local tmp
    printf '+ install -m %s -o %s -g %s <(render %q) %q\n' "$2" "$3" "$4" "${1#"$SRC/"}" "$5"
    render "$1" | diff "$1" - | sed -n 's/^> /#   rendered: /p' || true
    if [ "$DRY_RUN" = 0 ]; then
        tmp=$(mktemp)
        render "$1" >"$tmp"
        install -m "$2" -o "$3" -g "$4" "$tmp" "$5"
        rm -f "$tmp"
    fi
}

# --- Python 3.11 (the ROS 2 Jazzy wheels on PyPI are cp311) outside /home and /root ----------------------------
VENV=$PREFIX/.venv
if [ -x "$VENV/bin/python" ]; then
    note "venv $VENV exists: upgrading roslink-mqtt in it"
else
    if [ -z "$PYTHON" ]; then
        for candidate in /usr/bin/python3.11 /usr/local/bin/python3.11 python3.11 /usr/bin/python3 python3; do
            if command -v "$candidate" >/dev/null; then PYTHON=$(command -v "$candidate"); break; fi
        done
    fi
    [ -n "$PYTHON" ] && command -v "$PYTHON" >/dev/null || die "no python3.11 found: apt install python3.11 python3.11-venv (Debian 12), or give --python"
    "$PYTHON" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' \
        || die "$PYTHON is Python $("$PYTHON" -c 'import platform; print(platform.python_version())'); roslink-mqtt[bridge] needs 3.11 (the ROS 2 Jazzy wheels are cp311): give --python"
    real=$("$PYTHON" -c 'import os, sys; print(os.path.realpath(sys.executable))')
    case $real in
        /home/*|/root/*|/run/user/*) die "$PYTHON is $real: the units' ProtectHome=true hides it; use a system Python (--python /usr/bin/python3.11)" ;;
    esac
    "$PYTHON" -c 'import ensurepip, venv' 2>/dev/null || die "$PYTHON cannot create venvs: apt install python3.11-venv"
    note "Python: $real"
fi

# --- the system user(s) ------------------------------------------------------------------------------------------
if getent group roslink >/dev/null; then note "group roslink exists"; else run groupadd --system roslink; fi
if getent passwd roslink >/dev/null; then
    note "user roslink exists"
else
    run useradd --system --gid roslink --home-dir /nonexistent --no-create-home --shell /usr/sbin/nologin roslink
fi
if want bridge && [ "$BRIDGE_USER" != roslink ]; then
    if getent passwd "$BRIDGE_USER" >/dev/null; then
        note "the bridge runs as the existing user $BRIDGE_USER (with the supplementary group roslink)"
    else
        run useradd --system --user-group --home-dir /nonexistent --no-create-home --shell /usr/sbin/nologin \
            "$BRIDGE_USER"
    fi
fi

# --- the venv -----------------------------------------------------------------------------------------------------
extras=()
want bridge && extras+=(bridge)
want broker && extras+=(broker)
extras_csv=$(IFS=,; echo "${extras[*]}")
run install -d -m 755 "$PREFIX"
[ -x "$VENV/bin/python" ] || run "$PYTHON" -m venv "$VENV"
if [ "$FROM_PYPI" = 1 ]; then
    run "$VENV/bin/pip" install --upgrade "roslink-mqtt[$extras_csv]"
else
    # Built from a copy (a build writes build/ into its source tree) and not editable: the units cannot see a
    # checkout under /home.
    note "building roslink-mqtt from a copy of $SRC (pyproject.toml, README.md, roslink_mqtt/)"
    build=/tmp/roslink-mqtt-source
    if [ "$DRY_RUN" = 0 ]; then
        build=$(mktemp -d)
        trap 'rm -rf "$build"' EXIT
        tar -C "$SRC" --exclude=__pycache__ -cf - pyproject.toml README.md roslink_mqtt | tar -C "$build" -xf -
    fi
    run "$VENV/bin/pip" install --upgrade "$build[$extras_csv]"
fi

# --- configuration ------------------------------------------------------------------------------------------------
run install -d -m 750 -o root -g roslink "$ETC"
if [ -n "$CONFIG" ]; then
    [ -e "$ETC/robots.yaml" ] && note "replacing $ETC/robots.yaml with $CONFIG"
    run install -m 640 -o root -g roslink "$CONFIG" "$ETC/robots.yaml"
else
    note "keeping $ETC/robots.yaml"
fi
if want bridge; then
    if [ -e "$ETC/bridge.env" ]; then
        note "keeping $ETC/bridge.env"
    else
        install_rendered "$SRC/bridge/roslink-mqtt-bridge.env" 600 root root "$ETC/bridge.env"
    fi
fi

# --- units --------------------------------------------------------------------------------------------------------
units=()
want bridge && units+=(roslink-mqtt-bridge) && install_rendered "$SRC/bridge/roslink-mqtt-bridge.service" 644 root root "$UNIT_DIR/roslink-mqtt-bridge.service"
want broker && units+=(roslink-mqtt-broker) && install_rendered "$SRC/broker/roslink-mqtt-broker.service" 644 root root "$UNIT_DIR/roslink-mqtt-broker.service"
if [ -d /run/systemd/system ]; then
    run systemctl daemon-reload
else
    note "systemd is not running here: systemctl daemon-reload skipped"
fi

echo
if [ "$DRY_RUN" = 1 ]; then echo "Dry run: nothing was changed."; else echo "Installed."; fi
echo "Next:"
want broker && echo "  sudoedit $ETC/robots.yaml                # robots, users, grants, broker listeners"
want bridge && echo "  sudoedit $ETC/bridge.env                 # ROSLINK_ROBOT, ROSLINK_PASSWORD, --url, ROS_DOMAIN_ID"
for unit in "${units[@]}"; do
    echo "  sudo systemctl enable --now $unit"
done
for unit in "${units[@]}"; do
    echo "  journalctl -u $unit -f"
done
