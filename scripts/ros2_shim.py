"""A minimal `ros2` for machines without ros2cli (ROS 2 from PyPI wheels).

Supports the subset global_loc's README uses, with the same ament-index lookup as
ros2cli: `ros2 run PKG EXE [args]`, `ros2 run PKG --help` (lists executables),
`ros2 pkg prefix PKG`, `ros2 pkg executables [PKG]`, `ros2 pkg list`.
Installed by scripts/setup.sh only when no real `ros2` is on the PATH.
"""
import os
import sys

from ament_index_python.packages import PackageNotFoundError, get_package_prefix, get_packages_with_prefixes

USAGE = ('usage: ros2 run PKG EXE [args...] | ros2 pkg prefix PKG | '
         'ros2 pkg executables [PKG] | ros2 pkg list\n'
         '(global_loc shim: a subset of ros2cli)')


def executables(pkg):
    """Executable files in PREFIX/lib/PKG, as ros2cli's `ros2 pkg executables` finds them."""
    lib_dir = os.path.join(get_package_prefix(pkg), 'lib', pkg)
    if not os.path.isdir(lib_dir):
        return []
    return sorted(name for name in os.listdir(lib_dir)
                  if os.path.isfile(os.path.join(lib_dir, name))
                  and os.access(os.path.join(lib_dir, name), os.X_OK))


def fail(message):
    print(message, file=sys.stderr)
    return 1


def main(argv):
    if len(argv) >= 2 and argv[0] == 'run':
        pkg = argv[1]
        try:
            exes = executables(pkg)
        except PackageNotFoundError:
            return fail(f'Package not found: {pkg}')
        if len(argv) == 2 or argv[2] in ('-h', '--help'):
            print(f'executables of {pkg}:\n' + '\n'.join(f'  {pkg} {e}' for e in exes))
            return 0
        exe = argv[2]
        if exe not in exes:
            return fail(f'No executable found: {exe} (package {pkg} has: {", ".join(exes)})')
        path = os.path.join(get_package_prefix(pkg), 'lib', pkg, exe)
        os.execv(path, [path] + argv[3:])
    if len(argv) >= 2 and argv[:2] == ['pkg', 'list']:
        print('\n'.join(sorted(get_packages_with_prefixes())))
        return 0
    if len(argv) == 3 and argv[:2] == ['pkg', 'prefix']:
        try:
            print(get_package_prefix(argv[2]))
        except PackageNotFoundError:
            return fail(f'Package not found: {argv[2]}')
        return 0
    if len(argv) >= 2 and argv[:2] == ['pkg', 'executables']:
        pkgs = argv[2:] or sorted(get_packages_with_prefixes())
        for pkg in pkgs:
            try:
                for exe in executables(pkg):
                    print(f'{pkg} {exe}')
            except PackageNotFoundError:
                return fail(f'Package not found: {pkg}')
        return 0
    return fail(USAGE)


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
