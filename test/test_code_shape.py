"""The package's shape as the developers' standards state it: small files and functions,
names and comments that point at things that exist. No ROS: the source is read as text."""
import ast
import pathlib
import re

PACKAGE = pathlib.Path(__file__).resolve().parents[1] / 'global_loc'
MAX_FILE_LINES = 350
MAX_ARGUMENTS = 6
MAX_FUNCTION_LINES = 60       # compiled (numba) kernels excepted: a kernel cannot call helpers cheaply
SOURCES = sorted(PACKAGE.rglob('*.py'))


def _is_kernel(fn: ast.FunctionDef) -> bool:
    return any('jit' in ast.unparse(d) for d in fn.decorator_list)


def test_no_file_is_over_350_lines():
    long = {str(p.relative_to(PACKAGE)): n for p in SOURCES if (n := len(p.read_text().splitlines())) > MAX_FILE_LINES}
    assert not long, long


def test_no_function_is_over_60_lines_outside_the_numba_kernels():
    long = {}
    for p in SOURCES:
        for fn in ast.walk(ast.parse(p.read_text())):
            if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)) and not _is_kernel(fn):
                name = f'{p.relative_to(PACKAGE)}:{fn.name}'
                if (n := fn.end_lineno - fn.lineno + 1) > MAX_FUNCTION_LINES:
                    long[name] = n
    assert not long, long


def _functions(tree: ast.Module):
    """(qualified name, function) of every function in a module: Class.method, outer.inner."""
    def walk(node, prefix):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                yield f'{prefix}{child.name}', child
                yield from walk(child, f'{prefix}{child.name}.')
            elif isinstance(child, ast.ClassDef):
                yield from walk(child, f'{prefix}{child.name}.')
            else:
                yield from walk(child, prefix)
    yield from walk(tree, '')


def _arguments(fn: ast.FunctionDef) -> int:
    """Its parameters, self and cls aside; keyword-only ones (defaulted or not), *args and
    **kwargs count."""
    a = fn.args
    named = [x for x in a.posonlyargs + a.args + a.kwonlyargs if x.arg not in ('self', 'cls')]
    return len(named) + (a.vararg is not None) + (a.kwarg is not None)


def test_no_function_takes_more_than_6_arguments_outside_the_numba_kernels():
    """Parameters that travel together are a type waiting to be named (a search's limits, a
    scan's laser, a goal): a function takes at most 6. A numba kernel may take more, its
    docstring saying why ("N arguments: why"): it takes no Python object cheaply."""
    wide, unexplained = {}, {}
    for p in SOURCES:
        for name, fn in _functions(ast.parse(p.read_text())):
            qualified, n = f'{p.relative_to(PACKAGE)}:{name}', _arguments(fn)
            if n <= MAX_ARGUMENTS:
                continue
            if not _is_kernel(fn):
                wide[qualified] = n
            elif f'{n} arguments' not in ' '.join((ast.get_docstring(fn) or '').split()):
                unexplained[qualified] = n
    assert not wide, wide
    assert not unexplained, unexplained


def test_every_package_path_the_source_names_exists():
    """A docstring's "see core/x.py" that outlived a move sends the reader nowhere."""
    named = re.compile(r'\b((?:core|ros|bench|sim)(?:/[a-z_0-9]+)*/[a-z_0-9]+\.py)\b')
    missing = [f'{p.relative_to(PACKAGE)}: {m}' for p in SOURCES for m in named.findall(p.read_text())
               if not (PACKAGE / m).is_file()]
    assert not missing, missing


def test_a_name_said_to_live_in_a_file_is_defined_there():
    """"`image_point` (core/pixel_kernels.py)": the file defines image_point."""
    placed = re.compile(r'`(\w+)`\s*\(((?:core|ros|bench|sim)(?:/[a-z_0-9]+)*/[a-z_0-9]+\.py)\)')
    wrong = [f'{p.relative_to(PACKAGE)}: {name} not in {path}' for p in SOURCES
             for name, path in placed.findall(' '.join(p.read_text().split()))
             if not re.search(rf'^(?:def|class) {name}\b|^{name}\s*=', (PACKAGE / path).read_text(), re.M)]
    assert not wrong, wrong


# Every tracked text file that code, tests or docs live in (not the generated logs and outputs).
TEXT_FILES = ('README.md', 'Makefile', 'setup.py', 'setup.cfg', 'package.xml', 'ruff.toml', '*.txt', '.ci/*',
              'config/*.yaml', 'launch/*.py', 'maps/*.yaml', 'scripts/*', 'global_loc_interfaces/**/*', 'docs/**/*.md',
              'test/*.py', 'benchmarks/**/*.py', 'benchmarks/**/*.md', 'benchmarks/**/*.json', 'benchmarks/**/*.csv',
              'benchmarks/**/*.txt', 'global_loc/**/*.py', 'global_loc/**/*.urdf')
# A work item by its number or letter, a ticket as a bare #N (an upstream one names its
# project: ros2/rmw_fastrtps#751), a work round or session by its date or as a unit of work.
WORK_REFERENCE = re.compile(
    r'\bdef test_d\d+_|\bD\d+(?:-D\d+)?\b(?=[,:;.) ]|$)|\b[Ss]top \d+\b(?![.,]\d)|\b[Hh]elpers? [A-Z]\b'
    r'|^\s*# -+ item \d+'
    r'|\b(?:[Ii]ssue|ISSUE|[Ii]tem|[Rr]ound|[Ss]ession|[Gg]ap|[Ff]ix|[Dd]efect|[Tt]icket|[Ff]inding|[Bb]ug)s?'
    r' #?\d+\b(?![.,]\d)'
    r'|(?<![\w/.-])#\d+\b'
    r'|\b(?:[Rr]ound|[Ss]ession|[Ss]print)s? (?:of|on) \d{4}-\d\d-\d\d'
    r'|\b(?:this|next|last|previous|later|a) (?:round|session|sprint)\b(?=[ ,;:.)]|$)(?! (?:trip|room|pillar)\b)',
    re.M)


def test_tests_and_comments_say_the_behaviour_not_a_defect_number():
    """Defect lists ("issue 18, D6"), work items, tickets, rounds and session numbers are not
    in the repository (history lives in git); a name like test_d4_* tells a reader nothing.
    Every text file is read: code, tests, docs, decision records, configuration, scripts."""
    root = PACKAGE.parent
    files = sorted({p for pattern in TEXT_FILES for p in root.glob(pattern) if p.is_file()})
    assert len(files) > 200 and root / 'config' / 'global_loc.yaml' in files
    hits = [f'{p.relative_to(root)}:{k + 1}: {m.group(0)}' for p in files if p.name != 'test_code_shape.py'
            for k, line in enumerate(p.read_text().splitlines()) for m in WORK_REFERENCE.finditer(line)]
    assert not hits, hits


def test_the_readme_and_the_server_page_state_the_clients_exit_codes():
    """The client's docstring is the source; the README and docs/SERVER.md say the same."""
    root = PACKAGE.parent
    text = (PACKAGE / 'ros' / 'client.py').read_text()
    codes = dict(re.findall(r'^  (\d)  (.+?)[:;,]', text.split('Exit codes:')[1].split('"""')[0], re.M))
    assert codes['2'] == 'bad arguments' and codes['3'].startswith('no server answered'), codes
    for page in (root / 'README.md', root / 'docs' / 'SERVER.md'):
        flat = ' '.join(page.read_text().split())
        assert '2 on bad arguments, 3 when no server answered' in flat, page


def test_the_architecture_layout_names_every_module():
    """docs/ARCHITECTURE.md's layout tree is where a new engineer looks for a module."""
    text = (PACKAGE.parent / 'docs' / 'ARCHITECTURE.md').read_text()
    layout = text[text.index('## Layout'):]
    missing = [str(p.relative_to(PACKAGE)) for p in SOURCES if p.name not in ('__init__.py', '__main__.py')
               and not re.search(rf'\b{re.escape(p.name)}\b', layout)]
    assert not missing, missing


def test_the_package_root_holds_only_its_entry_points():
    """Modules live in their rooms (core, io, offline, ros, sim, bench, testing), not loose at the top."""
    assert sorted(p.name for p in PACKAGE.glob('*.py')) == ['__init__.py', '__main__.py']


def test_every_decision_record_the_repository_cites_exists():
    """"docs/decisions/0010" in a comment, a parameter's description or a page sends the reader
    to a record; a renumbered or dropped record must not leave the citation behind."""
    root = PACKAGE.parent
    records = {p.name[:4] for p in (root / 'docs' / 'decisions').glob('[0-9][0-9][0-9][0-9]-*.md')}
    files = SOURCES + sorted((root / 'test').glob('*.py')) + sorted((root / 'docs').rglob('*.md'))
    cited = {(p.name, n) for p in files for n in re.findall(r'decisions/(\d{4})', p.read_text())}
    assert len(records) >= 10 and len(cited) >= 4
    assert not [c for c in cited if c[1] not in records], sorted(cited)


def test_a_request_reads_the_servers_configuration_once():
    """docs/ARCHITECTURE.md: a request reads one consistent snapshot - at admission (the
    request path's Job), and `served_map` again just before publishing (the one live read:
    map_server may have switched maps during the search)."""
    text = (PACKAGE / 'ros' / 'request_path.py').read_text()
    reads = re.findall(r'self\.c\.config\(\)(\[\'\w+\'\])?', text)
    assert sorted(reads) == ['', "['served_map']"], reads
