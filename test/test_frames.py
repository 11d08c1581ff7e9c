"""A tree of fixed frames composed (core/frames.py) and the quaternion maths it stands on
(core/transform.py): the one composition io/urdf.py, io/bag.py and the /tf_static reader share."""
import math

import numpy as np
import pytest

from global_loc.core.frames import compose, transform_matrix
from global_loc.core.mount3d import Mount3D
from global_loc.core.transform import Quaternion, quaternion_of_rpy, rotation_of_quaternion

ANGLES = [(0.0, 0.0, 0.0), (math.pi, 0.0, 0.0), (0.0, 0.0, math.pi), (0.3, -0.4, 2.5), (-1.2, 0.7, -3.0),
          (0.2, math.pi / 2, 0.5)]      # the last: pointing straight down, where roll and yaw blur


@pytest.mark.parametrize('rpy', ANGLES)
def test_a_quaternion_made_from_angles_is_the_rotation_of_those_angles(rpy):
    q = quaternion_of_rpy(*rpy)
    assert np.linalg.norm(q) == pytest.approx(1.0)
    assert np.allclose(rotation_of_quaternion(*q), Mount3D(0, 0, 0, *rpy).rotation(), atol=1e-12)
    assert np.allclose(Mount3D.from_quaternion(0, 0, 0, Quaternion(*q)).rotation(), Mount3D(0, 0, 0, *rpy).rotation(),
                       atol=1e-9)


@pytest.mark.parametrize('rpy', ANGLES)
def test_a_mounting_survives_its_matrix(rpy):
    mount = Mount3D(0.1, -0.2, 0.3, *rpy)
    assert np.allclose(Mount3D.from_matrix(mount.matrix()).matrix(), mount.matrix(), atol=1e-9)


def test_a_zero_or_non_finite_transform_is_refused():
    with pytest.raises(ValueError, match='finite and non-zero'):
        transform_matrix([0, 0, 0], [0, 0, 0, 0])
    with pytest.raises(ValueError, match='three finite numbers'):
        transform_matrix([0, float('nan'), 0], [0, 0, 0, 1])


def test_two_frames_compose_through_their_nearest_common_ancestor():
    """base_footprint -> base_link and base_footprint -> laser: the laser on base_link goes up
    from the laser and down to base_link (robot_state_publisher trees have such siblings)."""
    footprint_T_base = Mount3D(0.0, 0.0, 0.1, 0.0, 0.0, 0.3)
    footprint_T_laser = Mount3D(0.2, 0.0, 0.4, math.pi, 0.0, 0.0)
    parents = {'base_link': ('base_footprint', footprint_T_base.matrix()),
               'laser': ('base_footprint', footprint_T_laser.matrix())}
    chain = compose(parents, 'base_link', 'laser')
    assert np.allclose(chain.base_T_frame, np.linalg.inv(footprint_T_base.matrix()) @ footprint_T_laser.matrix())
    assert chain.frames == ('base_link', 'base_footprint', 'laser') and set(chain.composed) == {'base_link', 'laser'}
    assert compose(parents, 'base_link', 'base_link').frames == ('base_link',)
    assert compose(parents, 'base_link', 'camera') is None
