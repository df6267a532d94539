"""`roslink-mqtt fleet` checks ROS types without ROS (issue 13 item 7).

Type names and preset/type compatibility are checked when the fleet file loads, from a table of the
common_interfaces types shipped with the package (roslink_mqtt/config/interface_table.py). The table is
generated from the installed ROS wheels by tools/ros_interfaces.py; here it is checked against them, and
the preset lists against the bridge's own. A type from another package is a note, not an error.
"""

from __future__ import annotations

import importlib.util
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from roslink_mqtt.config import ConfigError, interfaces, parse_fleet
from roslink_mqtt.config.interface_table import TABLE
from roslink_mqtt.config.passwords import hash_password
from tests.support.no_ros import no_ros_env
from tests.support.procs import ROOT

HASH = hash_password("pw", iterations=1)


def fleet_text(rules: str = "", robot: str = "") -> str:
    return textwrap.dedent(f"""\
        robots:
          r1:
            system_id: 1
            key: k1
            password: "{HASH}"
        """) + robot + ("    rules:\n" + rules if rules else "")


def load_generator():
    spec = importlib.util.spec_from_file_location("ros_interfaces", ROOT / "tools" / "ros_interfaces.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# -- the table and the wheels ------------------------------------------------------------------------------------

def test_table_matches_the_installed_wheels() -> None:
    pytest.importorskip("rclpy")
    generator = load_generator()
    built = generator.build_table()
    assert built["packages"] == TABLE["packages"]
    assert set(built["msg"]) == set(TABLE["msg"]) and set(built["srv"]) == set(TABLE["srv"])
    assert built == TABLE, "run .venv/bin/python tools/ros_interfaces.py"
    assert generator.render(built) == (ROOT / "roslink_mqtt" / "config" / "interface_table.py").read_text()
    for required in ("geometry_msgs", "nav_msgs", "sensor_msgs", "std_msgs", "std_srvs"):
        assert required in TABLE["packages"]


def test_table_fields_are_the_ros_classes_fields() -> None:
    """Spot checks through rosidl's own classes (the generator reads the same, for every type)."""
    pytest.importorskip("rclpy")
    from nav_msgs.msg import Odometry
    from std_srvs.srv import SetBool

    assert TABLE["msg"]["nav_msgs/msg/Odometry"] == Odometry.get_fields_and_field_types()
    assert TABLE["srv"]["std_srvs/srv/SetBool"]["request"] == SetBool.Request.get_fields_and_field_types()


def test_preset_lists_are_the_bridges() -> None:
    pytest.importorskip("rclpy")
    from roslink_mqtt.bridge.core.presets import COMMAND_PRESETS, STATE_PRESETS
    from roslink_mqtt.bridge.core.safety import VELOCITY_TYPES
    from roslink_mqtt.bridge.ros.rules import SERVICE_TARGETS

    assert interfaces.STATE_PRESET_TYPES == {name: p.ros_types for name, p in STATE_PRESETS.items()}
    assert interfaces.COMMAND_PRESET_TYPES == {name: p.ros_types for name, p in COMMAND_PRESETS.items()}
    assert interfaces.SERVICE_TARGETS == SERVICE_TARGETS
    assert set(interfaces.VELOCITY_TYPES) == set(VELOCITY_TYPES)
    every_type = {t for types in interfaces.PRESET_TYPES.values() for t in types} | set(interfaces.SERVICE_TARGETS)
    assert all(t in TABLE["msg"] or t in TABLE["srv"] for t in every_type)


# -- the loader, without ROS -------------------------------------------------------------------------------------

@pytest.mark.parametrize(("rules", "error"), [
    ("      - {direction: mqtt_to_ros, ros_topic: goal, ros_type: geometry_msgs/msg/PoseStamped,\n"
     "         mqtt_topic: cmd/twist, preset: twist}\n",
     "robots.yaml:8 robots.r1.rules[0].preset: preset 'twist' needs ros_type geometry_msgs/msg/Twist or "
     "geometry_msgs/msg/TwistStamped, not geometry_msgs/msg/PoseStamped"),
    ("      - {direction: ros_to_mqtt, ros_topic: odom, ros_type: nav_msgs/msg/Odometryy, mqtt_topic: state/odom}\n",
     "robots.yaml:7 robots.r1.rules[0].ros_type: unknown type 'nav_msgs/msg/Odometryy': 'nav_msgs' has no msg "
     "'Odometryy' (did you mean 'nav_msgs/msg/Odometry'?)"),
    ("      - {direction: ros_to_mqtt, ros_topic: odom, ros_type: nav_msgs/msg/GetMap, mqtt_topic: state/odom}\n",
     "unknown type 'nav_msgs/msg/GetMap': 'nav_msgs' has no msg 'GetMap' (nav_msgs/srv/GetMap is a service)"),
    ("      - {direction: ros_to_mqtt, ros_topic: imu, ros_type: sensor_msgs/msg/Imu, mqtt_topic: state/gm,\n"
     "         preset: global_motion}\n",
     "rules[0].preset: preset 'global_motion' needs ros_type nav_msgs/msg/Odometry or "
     "geometry_msgs/msg/PoseStamped or geometry_msgs/msg/PoseWithCovarianceStamped, not sensor_msgs/msg/Imu"),
    ("      - {direction: mqtt_to_ros, ros_topic: arm, ros_type: std_srvs/srv/Trigerr, mqtt_topic: cmd/arm,"
     " preset: arm}\n",
     "rules[0].ros_type: unknown type 'std_srvs/srv/Trigerr': 'std_srvs' has no srv 'Trigerr' (did you mean "
     "'std_srvs/srv/Trigger'?)"),
    ("      - {direction: mqtt_to_ros, ros_topic: arm, ros_type: nav_msgs/srv/GetMap, mqtt_topic: cmd/arm,"
     " preset: arm}\n",
     "rules[0].preset: preset 'arm' can call std_srvs/srv/Trigger or std_srvs/srv/SetBool or std_srvs/srv/Empty, "
     "not nav_msgs/srv/GetMap"),
    ("      - {direction: ros_to_mqtt, ros_topic: hb, ros_type: std_msgs/msg/String, mqtt_topic: state/hb,"
     " preset: heartbeat}\n",
     "rules[0].preset: preset 'heartbeat' has no ROS conversion"),
    ("      - {direction: ros_to_mqtt, ros_topic: odom, ros_type: nav_msgs/msg/Odometry, mqtt_topic: state/odom,\n"
     "         fields: {x: pose.pose.positon.x}}\n",
     "robots.yaml:8 robots.r1.rules[0].fields.x: 'pose.pose.positon.x' is not a field of nav_msgs/msg/Odometry"),
    ("      - {direction: mqtt_to_ros, ros_topic: cmd_vel, ros_type: geometry_msgs/msg/Twist, mqtt_topic: drive,\n"
     "         on_demand: true}\n",
     "rules[0].on_demand: on_demand is not for velocity commands"),
])
def test_loader_refuses_bad_types_with_file_line_and_key(rules: str, error: str) -> None:
    with pytest.raises(ConfigError) as info:
        parse_fleet(fleet_text(rules), "robots.yaml")
    assert error in str(info.value)


def test_services_and_failsafe_actions_are_checked_too() -> None:
    with pytest.raises(ConfigError, match=r"robots.yaml:6 robots.r1.services\[0\].ros_type: unknown type "
                                          r"'std_srvs/srv/Resett'.*\(std_srvs srv types: Empty, SetBool, Trigger\)"):
        parse_fleet(fleet_text(robot="    services: [{ros_service: reset, ros_type: std_srvs/srv/Resett}]\n"),
                    "robots.yaml")
    with pytest.raises(ConfigError, match=r"bridge.on_failsafe\[0\].ros_type: unknown type 'std_msgs/msg/Emtpy'"):
        parse_fleet(fleet_text(robot="    bridge: {on_failsafe: [{ros_topic: cancel, ros_type: std_msgs/msg/Emtpy}]}"
                                     "\n"), "robots.yaml")


def test_types_outside_the_table_are_notes_not_errors() -> None:
    fleet = parse_fleet(fleet_text(
        "      - {direction: ros_to_mqtt, ros_topic: arm_state, ros_type: my_robot_msgs/msg/ArmState,"
        " mqtt_topic: state/arm}\n"
        "      - {direction: mqtt_to_ros, ros_topic: grip, ros_type: my_robot_msgs/msg/Grip, mqtt_topic: grip,\n"
        "         fields: {force: anything.goes}}\n",
        robot="    services: [{ros_service: home, ros_type: my_robot_msgs/srv/Home}]\n"), "robots.yaml")
    assert fleet.notes == (
        "robots.yaml:8 robots.r1.rules[0].ros_type: my_robot_msgs/msg/ArmState is not a common_interfaces type: it "
        "cannot be checked here; the bridge checks it at start",
        "robots.yaml:9 robots.r1.rules[1].ros_type: my_robot_msgs/msg/Grip is not a common_interfaces type: it "
        "cannot be checked here; the bridge checks it at start",
        "robots.yaml:6 robots.r1.services[0].ros_type: my_robot_msgs/srv/Home is not a common_interfaces type: it "
        "cannot be checked here; the bridge checks it at start",
    )
    with pytest.raises(ConfigError, match="preset 'twist' needs ros_type"):  # a preset still knows its types
        parse_fleet(fleet_text("      - {direction: mqtt_to_ros, ros_topic: v, ros_type: my_robot_msgs/msg/Vel,"
                               " mqtt_topic: cmd/twist, preset: twist}\n"), "robots.yaml")


# -- the command, as a user runs it, on a machine without ROS ----------------------------------------------------

def _fleet_cli(tmp_path: Path, text: str) -> subprocess.CompletedProcess:
    config = tmp_path / "robots.yaml"
    config.write_text(text)
    return subprocess.run([sys.executable, "-m", "roslink_mqtt.cli.main", "fleet", "--config", str(config)],
                          capture_output=True, text=True, cwd=ROOT, timeout=60, env=no_ros_env(tmp_path))


def test_fleet_command_fails_on_a_twist_preset_on_posestamped(tmp_path) -> None:
    out = _fleet_cli(tmp_path, fleet_text("      - {direction: mqtt_to_ros, ros_topic: goal, ros_type: "
                                          "geometry_msgs/msg/PoseStamped, mqtt_topic: cmd/twist, preset: twist}\n"))
    assert out.returncode == 2, out.stdout
    assert f"{tmp_path / 'robots.yaml'}:7 robots.r1.rules[0].preset: preset 'twist' needs ros_type " in out.stderr
    assert "Traceback" not in out.stderr


def test_fleet_command_fails_on_a_misspelled_type(tmp_path) -> None:
    out = _fleet_cli(tmp_path, fleet_text("      - {direction: ros_to_mqtt, ros_topic: odom, ros_type: "
                                          "nav_msgs/msg/Odometryy, mqtt_topic: state/odom}\n"))
    assert out.returncode == 2, out.stdout
    assert "robots.r1.rules[0].ros_type: unknown type 'nav_msgs/msg/Odometryy'" in out.stderr
    assert "did you mean 'nav_msgs/msg/Odometry'?" in out.stderr


def test_fleet_command_says_what_it_cannot_check(tmp_path) -> None:
    out = _fleet_cli(tmp_path, fleet_text("      - {direction: ros_to_mqtt, ros_topic: arm, ros_type: "
                                          "my_robot_msgs/msg/ArmState, mqtt_topic: state/arm}\n"))
    assert out.returncode == 0, out.stderr
    assert "1 not checked here" in out.stdout
    assert "note: " in out.stdout and "my_robot_msgs/msg/ArmState is not a common_interfaces type: it cannot be " \
                                      "checked here; the bridge checks it at start" in out.stdout


def test_the_check_imports_no_ros(tmp_path) -> None:
    code = textwrap.dedent(f"""
        import sys
        from roslink_mqtt.config import ConfigError, load_fleet
        load_fleet({str(ROOT / 'config' / 'robots.yaml')!r})
        try:
            load_fleet({str(tmp_path / 'bad.yaml')!r})
        except ConfigError as err:
            print("refused:", err)
        ros = sorted(m for m in sys.modules if m.split('.')[0] in ('rclpy', 'rosidl_parser', 'ament_index_python')
                     or m.split('.')[0].endswith(('_msgs', '_srvs', '_interfaces')))
        print("ros modules:", ros)
    """)
    (tmp_path / "bad.yaml").write_text(fleet_text("      - {direction: ros_to_mqtt, ros_topic: odom, "
                                                  "ros_type: nav_msgs/msg/Odometryy, mqtt_topic: state/odom}\n"))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=60,
                         env=no_ros_env(tmp_path))
    assert "refused:" in out.stdout and "Odometryy" in out.stdout, out.stderr
    assert "ros modules: []" in out.stdout, out.stdout
