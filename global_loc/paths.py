"""Where the package's shipped files are, without ROS: the repository checkout (a
symlink install points here too). The ROS node prefers the ament index share dir."""
import os

PACKAGE_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def default_map_yaml() -> str:
    """The shipped office map; $GLOBAL_LOC_MAP overrides it."""
    return os.environ.get('GLOBAL_LOC_MAP') or os.path.join(PACKAGE_ROOT, 'maps', 'office.yaml')
