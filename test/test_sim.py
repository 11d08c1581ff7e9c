"""The pybullet simulator through its Python API (no ROS)."""
import math

import numpy as np
import pytest

from global_loc.core.transform import Rigid2D
from global_loc.sim.laser import LaserConfig
from global_loc.sim.raycast import simulate_scan
from global_loc.sim.simulator import BASE_T_LASER, Simulator
from global_loc.sim.world import merge_cells_into_boxes


@pytest.fixture(scope='module')
def sim(office_map):
    s = Simulator(office_map, LaserConfig(noise_std=0.0, dropout=0.0))
    yield s
    s.close()


def test_merged_boxes_cover_exactly_the_occupied_cells(office_map):
    boxes = merge_cells_into_boxes(office_map.occupied)
    covered = np.zeros(office_map.occupied.shape, dtype=int)
    for r0, c0, r1, c1 in boxes:
        covered[r0:r1, c0:c1] += 1
    assert np.array_equal(covered, office_map.occupied.astype(int))
    assert len(boxes) < office_map.occupied.sum() / 50


def test_scan_agrees_with_the_numpy_ray_caster_at_a_teleported_pose(sim, office_map):
    truth = Rigid2D(18.0, 4.5, -2.2)
    sim.place(truth)
    assert sim.true_pose().distance_to(truth)[0] < 1e-6
    scan = sim.scan()
    reference = simulate_scan(office_map, truth * BASE_T_LASER, 270.0, 541, 20.0)
    both = np.isfinite(scan.ranges) & np.isfinite(reference.ranges)
    assert both.mean() > 0.95
    # pybullet hits the wall surface, the ray caster the cell it marches into: < 1-2 cells apart.
    assert np.median(np.abs(scan.ranges[both] - reference.ranges[both])) < 0.05


def test_wheels_turn_and_drive_the_robot(sim):
    sim.place(Rigid2D(3.0, 4.0, 0.0))
    sim.drive(0.0, 0.5, 2.0)
    turned = sim.true_pose()
    assert math.degrees(turned.yaw) == pytest.approx(math.degrees(1.0), abs=12)
    sim.drive(0.3, 0.0, 2.0)
    moved = sim.true_pose()
    assert math.hypot(moved.x - turned.x, moved.y - turned.y) == pytest.approx(0.6, abs=0.1)


def test_clutter_shows_in_the_scan(office_map):
    s = Simulator(office_map, LaserConfig(noise_std=0.0, dropout=0.0))
    try:
        pose = Rigid2D(12.0, 8.0, 0.0)
        s.place(pose)
        before = s.scan().ranges
        from global_loc.sim.simulator import ClutterObject
        s.add_clutter([ClutterObject(13.5, 8.0, (0.25,))])     # a person 1.34 m ahead of the laser
        after = s.scan().ranges
        ahead = len(after) // 2
        # Bullet pads convex shapes such as cylinders with its ~0.04 m collision margin.
        assert after[ahead] == pytest.approx(1.5 - 0.16 - 0.25, abs=0.06)
        assert before[ahead] > 5
    finally:
        s.close()


def test_noise_and_dropout(office_map):
    s = Simulator(office_map, LaserConfig(noise_std=0.02, dropout=0.1), seed=3)
    try:
        s.place(Rigid2D(3.0, 4.0, 0.7))
        ranges = s.scan().ranges
        assert 0.05 < np.isnan(ranges).mean() < 0.16
    finally:
        s.close()
