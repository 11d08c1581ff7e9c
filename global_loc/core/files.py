"""Reading the package's small text files - map YAMLs, map-set files, the stored pose - so
that no file can hang a request, exhaust memory or flood a log: only a regular file is
opened (reading a FIFO blocks until a writer comes, maybe never), at most MAX_TEXT_BYTES
are read, YAML is parsed without aliases (a few hundred bytes of nested aliases, a
"billion laughs" file, expand to gigabytes), a parse that recurses too deep is an error
like any other, and a value echoed in an error is cut to a line (`brief`)."""
from __future__ import annotations

import errno
import os
import stat

import yaml

# A map YAML, a map-set file or a stored pose is a few hundred bytes; a thousand times that
# is still no file of this package's
MAX_TEXT_BYTES = 1 << 20
BRIEF_CHARS = 80


class UnreadableFile(ValueError):
    """A file that is not a readable regular file, too big, or not parsed; the message says
    which and why, without the path (the caller names the file)."""


def brief(value, limit: int = BRIEF_CHARS) -> str:
    """repr(value) cut to `limit` characters: an error's echo of what it refused."""
    text = repr(value)
    return text if len(text) <= limit else f'{text[:limit - 20]}... ({len(text)} characters)'


def not_a_regular_file(path: str) -> str:
    """'' when `path` is a readable regular file (or a symlink to one); otherwise what it is
    instead: missing, a dangling symlink, a symlink loop, a directory, a FIFO, a device or
    a socket, or unreadable - not just "not found"."""
    try:
        mode = os.stat(path).st_mode
    except OSError as e:
        if e.errno == errno.ELOOP:
            return 'is a symlink loop (it never reaches a file)'
        if os.path.islink(path):
            return f'is a symlink to {os.readlink(path)!r}, which does not exist'
        if e.errno == errno.ENOENT:
            return 'not found'
        return f'cannot be accessed: {e.strerror}'
    kinds = [(stat.S_ISDIR, 'a directory'), (stat.S_ISFIFO, 'a FIFO (named pipe)'),
             (stat.S_ISCHR, 'a character device'), (stat.S_ISBLK, 'a block device'), (stat.S_ISSOCK, 'a socket')]
    for is_kind, kind in kinds:
        if is_kind(mode):
            return f'is {kind}, not a file'
    if not os.access(path, os.R_OK):
        return 'is not readable (permission denied)'
    return ''


def read_small_text(path: str, max_bytes: int = MAX_TEXT_BYTES) -> str:
    """The UTF-8 text of a regular file of at most max_bytes; UnreadableFile otherwise. The
    file is opened without blocking and checked after opening, so a FIFO put at the path
    after a check still cannot block the read."""
    problem = not_a_regular_file(path)
    if problem:
        raise UnreadableFile(problem)
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, 'O_NONBLOCK', 0))
    except OSError as e:
        raise UnreadableFile(f'cannot be opened: {e.strerror}') from None
    with os.fdopen(fd, 'rb') as f:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise UnreadableFile('is not a regular file')
        data = f.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise UnreadableFile(f'is larger than {max_bytes} bytes (no file of this kind is)')
    try:
        return data.decode('utf-8')
    except UnicodeDecodeError as e:
        raise UnreadableFile(f'is not UTF-8 text: {e}') from None


class _NoAliasLoader(yaml.SafeLoader):
    """YAML's safe loader refusing aliases (`*name`): the only way a small file expands."""

    def compose_node(self, parent, index):
        if self.check_event(yaml.AliasEvent):
            mark = self.peek_event().start_mark
            raise yaml.composer.ComposerError(None, None, 'aliases (*name) are not allowed in this file', mark)
        return super().compose_node(parent, index)


def load_yaml_text(text: str):
    """The document of a YAML text without aliases; UnreadableFile when it does not parse."""
    try:
        return yaml.load(text, Loader=_NoAliasLoader)     # noqa: S506 - a SafeLoader subclass
    except yaml.MarkedYAMLError as e:      # the problem and where, on one line (not the echoed text)
        mark = e.problem_mark or e.context_mark
        where = f' (line {mark.line + 1}, column {mark.column + 1})' if mark is not None else ''
        raise UnreadableFile(f'is not valid YAML: {str(e.problem or e.context)[:200]}{where}') from None
    except yaml.YAMLError as e:
        first = str(e).splitlines()[0][:200] if str(e) else type(e).__name__
        raise UnreadableFile(f'is not valid YAML: {first}') from None
    except RecursionError:
        raise UnreadableFile('is not valid YAML: nested too deep') from None


def read_yaml_file(path: str, max_bytes: int = MAX_TEXT_BYTES):
    """read_small_text then load_yaml_text."""
    return load_yaml_text(read_small_text(path, max_bytes))
