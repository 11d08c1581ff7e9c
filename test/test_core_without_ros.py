"""The ROS boundary: every module of global_loc/core, io, offline (the command line) and sim imports with
rclpy, every *_msgs package and global_loc_interfaces made unimportable."""
import pkgutil
import subprocess
import sys

import pytest

import global_loc.core
import global_loc.io
import global_loc.offline
import global_loc.sim
from conftest import PYBULLET_INSTALLED

BLOCKER = '''
import importlib.abc, sys

class NoRos(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        top = name.split('.')[0]
        if top in ('rclpy', 'global_loc_interfaces') or top.endswith('_msgs'):
            raise ImportError(f'{name} is blocked: the core must not need ROS')
        return None

sys.meta_path.insert(0, NoRos())
import importlib
for name in sys.argv[1:]:
    importlib.import_module(name)
print('imported', len(sys.argv) - 1)
'''


def modules_of(package) -> list[str]:
    return [package.__name__] + [m.name for m in pkgutil.walk_packages(package.__path__, package.__name__ + '.')]


@pytest.mark.process
def test_core_and_simulator_import_without_ros():
    names = (modules_of(global_loc.core) + modules_of(global_loc.io) + modules_of(global_loc.offline)
             + modules_of(global_loc.sim))
    assert 'global_loc.core.matchers.bnb.verdict' in names and 'global_loc.sim.simulator' in names
    if not PYBULLET_INSTALLED:       # the compatibility run: the one module that needs pybullet to import
        names.remove('global_loc.sim.simulator')
    assert 'global_loc.offline.cli' in names
    out = subprocess.run([sys.executable, '-c', BLOCKER, *names], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == f'imported {len(names)}'


@pytest.mark.process
def test_the_blocker_blocks():
    """So the test above cannot pass by accident: a ROS module does not import."""
    out = subprocess.run([sys.executable, '-c', BLOCKER, 'global_loc.ros.convert'], capture_output=True, text=True,
                         timeout=300)
    assert out.returncode != 0 and 'is blocked: the core must not need ROS' in out.stderr
