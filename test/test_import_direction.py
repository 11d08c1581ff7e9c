"""Which room may import which, read from the source (no import is run): the benchmark
is imported by nothing outside it; the test and demo harnesses (testing/) by nothing the
robot runs; bnb's internals by nothing outside matchers/ (its package's __init__ is its
face). io/ needing no ROS is test_core_without_ros.py's."""
import ast
import pathlib

PACKAGE = pathlib.Path(__file__).resolve().parents[1] / 'global_loc'


def imported(path: pathlib.Path) -> set[str]:
    """The global_loc modules a file imports, as dotted names (relative imports resolved)."""
    parts = list(path.relative_to(PACKAGE.parent).with_suffix('').parts)
    package = parts[:-1] if parts[-1] != '__init__' else parts[:-1]
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            base = package[:len(package) - node.level + 1] if node.level else []
            module = '.'.join(base + ([node.module] if node.module else []))
            # `from package import name`: the module it reads is the package (its face), unless
            # the names are its modules (`from . import x`)
            names.update([module] if node.module else [f'{module}.{a.name}' for a in node.names])
        elif isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
    return {n for n in names if n.startswith('global_loc')}


def room(path: pathlib.Path) -> str:
    return path.relative_to(PACKAGE).parts[0] if len(path.relative_to(PACKAGE).parts) > 1 else path.stem


SOURCES = sorted(PACKAGE.rglob('*.py'))


def offenders(rule) -> list[str]:
    return [f'{p.relative_to(PACKAGE)} imports {name}' for p in SOURCES for name in sorted(imported(p))
            if rule(p, name)]


def test_nothing_outside_the_benchmark_imports_it():
    assert not offenders(lambda p, name: name.startswith('global_loc.bench') and room(p) != 'bench')


def test_nothing_the_robot_runs_imports_the_test_harnesses():
    assert not offenders(lambda p, name: name.startswith('global_loc.testing') and room(p) not in ('bench', 'testing'))


def test_only_the_matchers_reach_into_bnb():
    def inside_bnb(name):
        return name.startswith('global_loc.core.matchers.bnb.')
    assert not offenders(lambda p, name: inside_bnb(name) and 'matchers' not in p.relative_to(PACKAGE).parts)


def test_the_rule_reader_sees_relative_imports():
    """So the tests above cannot pass by reading nothing."""
    names = imported(PACKAGE / 'bench' / 'suites.py')
    assert 'global_loc.io.carmen' in names and 'global_loc.bench.carmen' in names


def test_only_io_reads_recordings():
    """rosbags (the recording format) is read by io/ alone: the rest gets messages from it."""
    def reads_rosbags(path: pathlib.Path) -> bool:
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ''] if isinstance(node, ast.ImportFrom) else []
            if any(n.split('.')[0] == 'rosbags' for n in names):
                return True
        return False
    readers = {str(p.relative_to(PACKAGE)) for p in SOURCES if reads_rosbags(p)}
    assert readers and all(r.startswith('io/') for r in readers), readers


def test_the_installed_package_is_the_runtime_alone(monkeypatch):
    """setup.py installs what a robot runs: not the benchmark, nor the test and demo
    harnesses, nor the repository's benchmarks/ scripts (they run from the source tree)."""
    import pytest
    pytest.importorskip('setuptools', reason='reading setup.py needs setuptools (the compatibility venv has none)')
    from setuptools._distutils.core import run_setup
    root = PACKAGE.parent
    monkeypatch.chdir(root)           # setup.py finds its packages from where it is run
    packages = set(run_setup(str(root / 'setup.py'), stop_after='init').packages)
    assert {'global_loc', 'global_loc.core', 'global_loc.ros', 'global_loc.sim', 'global_loc.io'} <= packages
    assert not {p for p in packages if p.split('.')[:2] in (['global_loc', 'bench'], ['global_loc', 'testing'])
                or not p.startswith('global_loc')}, packages
