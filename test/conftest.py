import os

import pytest

from global_loc.map_io import load_map_yaml

REPO_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SHARED_DATA = os.path.normpath(os.path.join(REPO_ROOT, '..', 'shared', 'data'))
OFFICE_YAML = os.path.join(REPO_ROOT, 'maps', 'office.yaml')


def shared_path(*parts) -> str:
    """A file under ../shared/data, or skip the test saying what is missing."""
    path = os.path.join(SHARED_DATA, *parts)
    if not os.path.exists(path):
        pytest.skip(f'shared test data not present: {path} (the checkout needs ../shared beside it)')
    return path


@pytest.fixture(scope='session')
def office_map():
    return load_map_yaml(OFFICE_YAML)
