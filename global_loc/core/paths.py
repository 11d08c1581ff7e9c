"""Where the package's shipped files are: the install's share directory when the package
was installed through colcon (ament index), else this source checkout."""
import os

PACKAGE_ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def shipped(*parts: str) -> str:
    """A shipped file: in the install's share directory, else in this checkout."""
    try:
        from ament_index_python.packages import get_package_share_directory
        return os.path.join(get_package_share_directory('global_loc'), *parts)
    except Exception:   # no ament index, or the package is not installed: the checkout
        return os.path.join(PACKAGE_ROOT, *parts)


def default_map_yaml() -> str:
    """The shipped office map; $GLOBAL_LOC_MAP overrides it."""
    if os.environ.get('GLOBAL_LOC_MAP'):
        return os.environ['GLOBAL_LOC_MAP']
    return shipped('maps', 'office.yaml')


def sim_params_file() -> str:
    """The server's parameters for the shipped simulator: where its sensors sit on the base."""
    return shipped('config', 'sim.yaml')
