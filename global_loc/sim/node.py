"""`ros2 run global_loc sim` (the pybullet simulator node arrives with its own issue)."""
import sys


def main():
    print('global_loc sim: not implemented yet (the pybullet simulator is a later issue)', file=sys.stderr)
    sys.exit(1)
