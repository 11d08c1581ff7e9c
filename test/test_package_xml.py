"""package.xml is what `rosdep install --from-paths src` reads on a real ROS 2 install: every
third-party module imported by global_loc/, launch/, setup.py and test/ must have its rosdep
key declared there, in a scope that has it when it is needed, and nothing may be declared
that nothing uses. The imports are read with ast (an import inside a function counts), and
so are the packages whose executables a launch file starts (Node(package='...'))."""
import ast
import sys
import xml.etree.ElementTree as ElementTree
from pathlib import Path

from conftest import REPO_ROOT

ROOT = Path(REPO_ROOT)

# import name -> rosdep key. ROS packages are keyed by their package name (jazzy's
# distribution.yaml); the others by ros/rosdistro's rosdep/python.yaml, where *-pip keys are
# installed by pip (no Ubuntu package).
ROSDEP_KEYS = {
    'action_msgs': 'action_msgs',
    'ament_index_python': 'ament_index_python',
    'builtin_interfaces': 'builtin_interfaces',
    'cv2': 'python3-opencv',
    'diagnostic_msgs': 'diagnostic_msgs',
    'geometry_msgs': 'geometry_msgs',
    'global_loc_interfaces': 'global_loc_interfaces',
    'hypothesis': 'python3-hypothesis',
    'launch': 'launch',
    'launch_ros': 'launch_ros',
    'lifecycle_msgs': 'lifecycle_msgs',
    'matplotlib': 'python3-matplotlib',
    'nav2_lifecycle_manager': 'nav2_lifecycle_manager',   # launched, not imported
    'nav_msgs': 'nav_msgs',
    'numba': 'python3-numba',
    'numpy': 'python3-numpy',
    'pybullet': 'python3-pybullet-pip',
    'pytest': 'python3-pytest',
    'rcl_interfaces': 'rcl_interfaces',
    'rclpy': 'rclpy',
    'rosbags': 'python3-rosbags-pip',
    'scipy': 'python3-scipy',
    'sensor_msgs': 'sensor_msgs',
    'setuptools': 'python3-setuptools',
    'std_msgs': 'std_msgs',
    'std_srvs': 'std_srvs',
    'tf2_msgs': 'tf2_msgs',
    'tf2_ros': 'tf2_ros_py',          # the Python tf2 API is package tf2_ros_py
    'tqdm': 'python3-tqdm',
    'visualization_msgs': 'visualization_msgs',
    'yaml': 'python3-yaml',
}

# Which package.xml tags make a key available (REP 149): <depend> is build + exec.
SCOPE_TAGS = {
    'build': {'depend', 'build_depend', 'buildtool_depend'},
    'exec': {'depend', 'exec_depend'},
    'test': {'depend', 'exec_depend', 'test_depend'},
}
DEPENDENCY_TAGS = set().union(*SCOPE_TAGS.values())


def sources_by_scope() -> dict[str, list[Path]]:
    return {'build': [ROOT / 'setup.py'],
            'exec': sorted((ROOT / 'global_loc').rglob('*.py')) + sorted((ROOT / 'launch').glob('*.py')),
            'test': sorted((ROOT / 'test').rglob('*.py'))}


def own_modules() -> set[str]:
    """The package itself, the repository's benchmark experiments and the test directory's
    modules (conftest, ros_helpers, ...)."""
    return {'global_loc', 'benchmarks'} | {p.stem for p in (ROOT / 'test').glob('*.py')}


def used_names(node) -> list[str]:
    """The modules an import statement imports, or the package a launch Node(package=...) runs."""
    if isinstance(node, ast.Import):
        return [alias.name for alias in node.names]
    if isinstance(node, ast.ImportFrom) and node.level == 0:
        return [node.module]
    if isinstance(node, ast.Call) and getattr(node.func, 'id', getattr(node.func, 'attr', None)) == 'Node':
        return [k.value.value for k in node.keywords if k.arg == 'package' and isinstance(k.value, ast.Constant)]
    return []


def third_party_imports(paths) -> dict[str, set[str]]:
    """Top-level module (or launched package) -> files (relative) using it, stdlib and own
    modules left out."""
    skip = set(sys.stdlib_module_names) | own_modules()
    found: dict[str, set[str]] = {}
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names = used_names(node)
            for top in {name.split('.')[0] for name in names} - skip:
                found.setdefault(top, set()).add(str(path.relative_to(ROOT) if path.is_relative_to(ROOT) else path))
    return found


def declared(package_xml: Path) -> dict[str, set[str]]:
    """rosdep key -> the package.xml tags declaring it."""
    keys: dict[str, set[str]] = {}
    for element in ElementTree.parse(package_xml).getroot():
        if element.tag in DEPENDENCY_TAGS:
            keys.setdefault(element.text.strip(), set()).add(element.tag)
    return keys


def dependency_problems(package_xml: Path, sources: dict[str, list[Path]]) -> list[str]:
    """Each import without a key, or without its key declared in its scope; each declared
    key nothing imports; each table entry nothing imports. Empty when package.xml is right."""
    keys = declared(package_xml)
    problems, used = [], set()
    for scope, paths in sources.items():
        for module, files in sorted(third_party_imports(paths).items()):
            where = ', '.join(sorted(files)[:3]) + (' ...' if len(files) > 3 else '')
            key = ROSDEP_KEYS.get(module)
            if key is None:
                problems.append(f'{module} (imported by {where}) has no rosdep key in ROSDEP_KEYS: look it up in '
                                f'ros/rosdistro rosdep/python.yaml or base.yaml, add it there and to package.xml')
                continue
            used.add(module)
            if not keys.get(key, set()) & SCOPE_TAGS[scope]:
                tags = ' or '.join(f'<{t}>' for t in sorted(SCOPE_TAGS[scope]))
                problems.append(f'{module} (imported by {where}) needs {tags}{key}</...> in package.xml; '
                                f'declared as: {sorted(keys.get(key, ())) or "nothing"}')
    used_keys = {ROSDEP_KEYS[m] for m in used}
    problems += [f'package.xml declares {key} ({", ".join(sorted(tags))}) but nothing imports it'
                 for key, tags in sorted(keys.items()) if key not in used_keys]
    problems += [f'ROSDEP_KEYS has {module} but nothing imports it' for module in sorted(set(ROSDEP_KEYS) - used)]
    return problems


def test_package_xml_declares_every_import_and_nothing_else():
    problems = dependency_problems(ROOT / 'package.xml', sources_by_scope())
    assert not problems, 'package.xml is out of date:\n' + '\n'.join(problems)


def test_an_undeclared_import_is_reported(tmp_path):
    """The check itself: a module importing a library package.xml does not declare."""
    extra = tmp_path / 'uses_shapely.py'
    extra.write_text('def area():\n    import shapely\n    return shapely\n')
    sources = sources_by_scope()
    sources['exec'].append(extra)
    problems = [p for p in dependency_problems(ROOT / 'package.xml', sources) if 'shapely' in p]
    assert len(problems) == 1 and 'has no rosdep key' in problems[0], problems


def test_a_key_declared_in_the_wrong_scope_is_reported(tmp_path):
    """pytest declared for tests only, imported by the package: rosdep would not install it on a robot."""
    extra = tmp_path / 'uses_pytest.py'
    extra.write_text('import pytest\n')
    sources = sources_by_scope()
    sources['exec'].append(extra)
    problems = dependency_problems(ROOT / 'package.xml', sources)
    assert any(p.startswith('pytest (imported by') and "['test_depend']" in p for p in problems), problems
