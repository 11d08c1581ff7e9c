"""The pages name only parameters the nodes declare: a `-p name:=value` (or `name:=value`) in
the README or docs/ that the server, the simulator or the launch file does not know would
fail a user who copies it (an undeclared override is silently ignored by rclpy)."""
import pathlib
import re

from global_loc.ros.parameters import BY_NAME

ROOT = pathlib.Path(__file__).resolve().parents[1]
PAGES = [ROOT / 'README.md'] + sorted((ROOT / 'docs').glob('*.md'))
ASSIGNED = re.compile(r'(?<![\w.-])([a-z][a-z0-9_]*(?:\.[a-z0-9_<>]+)*):=')


def sim_parameters() -> set[str]:
    source = (ROOT / 'global_loc' / 'ros' / 'sim_node.py').read_text()
    return set(re.findall(r"\bparam\('([a-z0-9_]+)'", source))


def launch_arguments() -> set[str]:
    source = (ROOT / 'launch' / 'global_loc.launch.py').read_text()
    return set(re.findall(r"DeclareLaunchArgument\('([a-z0-9_]+)'", source))


def known(name: str) -> bool:
    # per-sensor parameters are named after the sensor: sensors.<name>.mount, .frame_id, ...
    return (name in BY_NAME or name in sim_parameters() or name in launch_arguments() or name == 'use_sim_time'
            or re.fullmatch(r'sensors\.[\w<>]+\.\w+', name) is not None)


def test_every_parameter_a_page_sets_is_declared_by_the_server_or_the_simulator():
    named = {(p.name, n) for p in PAGES for n in ASSIGNED.findall(p.read_text())}
    assert len(named) >= 15, named      # the pattern reads the pages' commands
    unknown = sorted((page, n) for page, n in named if not known(n))
    assert not unknown, unknown


def test_an_undeclared_name_is_caught():
    assert not known('scan_topik') and known('scan_topic') and known('rear_laser') and known('sensors.rear.mount')
