"""The pybullet Pioneer 3-DX scan simulator (headless, DIRECT mode), without ROS.

    sim = Simulator(load_map_yaml('maps/office.yaml'), LaserConfig(fov_deg=270))
    sim.place(Rigid2D(3.0, 4.0, 0.7))          # the kidnapping
    scan = sim.scan()                          # a global_loc.core.scan.Scan
    sim.drive(v=0.0, w=0.5, duration=1.0)      # wheels, physics stepped at 240 Hz
    sim.true_pose()                            # base_link in the map frame
    sim.odom                                   # base_link in the odom frame, from the wheels (noisy)

The laser is cast with rayTestBatch from the laser link's pose, so clutter added with
`add_clutter` (boxes, cylinders not in the map) shows in the scans. Optional sensors:
a rear laser (`rear_laser`: `sim.rear_scan()`, at the back facing back, REAR_LASER_MOUNT)
and a 16-ring 3D lidar (`lidar`: `sim.lidar_points()`, LIDAR_MOUNT) in a world extruded
in 3D (world.obstacle_heights); without them the simulator is the 2D one it always was.
"""
from __future__ import annotations

import math
import os
import tempfile
from dataclasses import dataclass

import numpy as np
import pybullet as p

from ..core.map_io import OccupancyMap
from ..core.mount3d import Mount3D
from ..core.scan import Scan
from ..core.transform import Rigid2D
from ..io.urdf import bodies_only
from .laser import LaserConfig
from .lidar3d import Lidar3DConfig
from .raycast import sample_free_poses
from .robot import FRONT_LASER_MOUNT, LIDAR_MOUNT, REAR_LASER_MOUNT, URDF
from .world import add_map_walls, obstacle_heights

# The sensors on base_link as the URDF's fixed joints put them (sim/robot.py): the front
# laser (laser_joint; its rays leave from that link), the optional rear laser on the
# chassis' back edge facing back, the optional 3D lidar; seen from above for the 2D methods.
BASE_T_LASER = FRONT_LASER_MOUNT.upright()
LASER_HEIGHT = FRONT_LASER_MOUNT.z
BASE_T_REAR_LASER = REAR_LASER_MOUNT.upright()
RAY_BATCH = 16384    # pybullet's largest rayTestBatch
WHEEL_RADIUS = 0.0975
WHEEL_SEPARATION = 0.33
PHYSICS_HZ = 240.0


@dataclass
class OdometryNoise:
    """Wheel odometry's errors: each wheel's travel is off by a random share (scale_std,
    per update), and the heading drifts by yaw_drift rad per metre driven (an unequal
    wheel radius), so the odometry pose walks away from the truth as real ones do."""
    scale_std: float = 0.02
    yaw_drift: float = 0.01


@dataclass
class ClutterObject:
    """A box (size = (sx, sy)) or cylinder (size = (radius,)) standing on the floor."""
    x: float
    y: float
    size: tuple
    height: float = 1.0
    yaw: float = 0.0


def _load_bodies(urdf: str, client) -> int:
    """The robot as pybullet's multibody: the URDF's links that have a body (io/urdf.py
    `bodies_only`). The optional sensors' links are frames, cast from by their mountings;
    as links they would change the multibody, and so every seeded run's physics."""
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, os.path.basename(urdf))
        with open(path, 'w') as f:
            f.write(bodies_only(urdf))
        return p.loadURDF(path, [0, 0, 0], physicsClientId=client)


class Simulator:
    def __init__(self, occupancy_map: OccupancyMap, laser: LaserConfig | None = None, seed: int = 0,
                 odometry_noise: OdometryNoise | None = None, rear_laser: LaserConfig | None = None,
                 lidar: Lidar3DConfig | None = None):
        self.map = occupancy_map
        self.laser = laser or LaserConfig()
        self.rear_laser, self.lidar = rear_laser, lidar
        self.odometry_noise = odometry_noise or OdometryNoise()
        self.rng = np.random.default_rng(seed)
        # the optional sensors' noise from streams of their own: the front laser's and the
        # odometry's draws are the same with or without them
        self.rear_rng, self.lidar_rng = np.random.default_rng([seed, 1]), np.random.default_rng([seed, 2])
        self.client = p.connect(p.DIRECT)
        p.setGravity(0, 0, -9.81, physicsClientId=self.client)
        p.setTimeStep(1.0 / PHYSICS_HZ, physicsClientId=self.client)
        plane = p.createCollisionShape(p.GEOM_PLANE, physicsClientId=self.client)
        p.createMultiBody(0, plane, physicsClientId=self.client)
        self.num_wall_boxes = add_map_walls(self.client, occupancy_map,
                                            obstacle_heights(occupancy_map) if lidar else None)
        self.robot = _load_bodies(URDF, self.client)
        joints = {p.getJointInfo(self.robot, j, physicsClientId=self.client)[1].decode(): j
                  for j in range(p.getNumJoints(self.robot, physicsClientId=self.client))}
        self.left, self.right = joints['left_wheel_joint'], joints['right_wheel_joint']
        self.laser_link = joints['laser_joint']
        caster = joints['caster_joint']
        p.changeDynamics(self.robot, caster, lateralFriction=0.0, rollingFriction=0.0, physicsClientId=self.client)
        self.clutter_ids = []
        # pybullet places and reports a body by its centre of mass, not by its URDF link
        # frame: base_link -> centre of mass (the URDF's inertial origin)
        lx, ly, self.com_height = p.getDynamicsInfo(self.robot, -1, physicsClientId=self.client)[3]
        self.base_T_com = Rigid2D(lx, ly, 0.0)
        self.odom = Rigid2D()                  # base_link in the odom frame (starts at the odom origin)
        self._odom_from = self.true_pose()

    def close(self) -> None:
        if self.client is not None and p.isConnected(self.client):
            p.disconnect(self.client)
        self.client = None

    def place(self, pose: Rigid2D) -> None:
        """Teleport the robot (base_link) to a pose in the map frame, at rest."""
        com = pose * self.base_T_com
        p.resetBasePositionAndOrientation(self.robot, [com.x, com.y, self.com_height],
                                          p.getQuaternionFromEuler([0, 0, pose.yaw]), physicsClientId=self.client)
        p.resetBaseVelocity(self.robot, [0, 0, 0], [0, 0, 0], physicsClientId=self.client)
        self._odom_from = self.true_pose()
        for j in (self.left, self.right):
            p.setJointMotorControl2(self.robot, j, p.VELOCITY_CONTROL, targetVelocity=0.0, force=20.0,
                                    physicsClientId=self.client)

    def true_pose(self) -> Rigid2D:
        """base_link in the map frame."""
        (x, y, _), q = p.getBasePositionAndOrientation(self.robot, physicsClientId=self.client)
        return Rigid2D(x, y, p.getEulerFromQuaternion(q)[2]) * self.base_T_com.inverse()

    def drive(self, v: float, w: float, duration: float) -> None:
        """Drive the wheels for (v m/s, w rad/s) during `duration` seconds of simulated time."""
        left = (v - w * WHEEL_SEPARATION / 2.0) / WHEEL_RADIUS
        right = (v + w * WHEEL_SEPARATION / 2.0) / WHEEL_RADIUS
        for j, speed in ((self.left, left), (self.right, right)):
            p.setJointMotorControl2(self.robot, j, p.VELOCITY_CONTROL, targetVelocity=speed, force=20.0,
                                    physicsClientId=self.client)
        for _ in range(max(1, int(round(duration * PHYSICS_HZ)))):
            p.stepSimulation(physicsClientId=self.client)
        self.update_odometry()

    def update_odometry(self) -> None:
        """Move the odometry pose by the body's motion since the last update, as the two
        wheels' travel with the odometry noise (each wheel's share, the heading's drift).
        The body's motion, not the simulated wheels' turn: pybullet's wheel contacts slip
        10-20% on a turn, far more than a real Pioneer's. A teleport (place) moves the
        robot, not its odometry: a kidnapping."""
        now = self.true_pose()
        step = self._odom_from.inverse() * now
        self._odom_from = now
        ds = math.copysign(math.hypot(step.x, step.y), step.x)
        left, right = ds - step.yaw * WHEEL_SEPARATION / 2.0, ds + step.yaw * WHEEL_SEPARATION / 2.0
        noise = self.odometry_noise
        if noise.scale_std > 0:
            left, right = np.array([left, right]) * (1.0 + self.rng.normal(0.0, noise.scale_std, 2))
        ds = (left + right) / 2.0
        dyaw = (right - left) / WHEEL_SEPARATION + noise.yaw_drift * abs(ds)
        self.odom = self.odom * Rigid2D(float(ds * math.cos(dyaw / 2.0)), float(ds * math.sin(dyaw / 2.0)),
                                        float(dyaw))

    def add_clutter(self, objects: list[ClutterObject]) -> None:
        for o in objects:
            if len(o.size) == 1:
                shape = p.createCollisionShape(p.GEOM_CYLINDER, radius=o.size[0], height=o.height,
                                               physicsClientId=self.client)
            else:
                shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=[o.size[0] / 2, o.size[1] / 2, o.height / 2],
                                               physicsClientId=self.client)
            self.clutter_ids.append(p.createMultiBody(0, shape, -1, [o.x, o.y, o.height / 2],
                                                      p.getQuaternionFromEuler([0, 0, o.yaw]),
                                                      physicsClientId=self.client))

    def random_clutter(self, count: int, keep_clear_of: Rigid2D | None = None, clear_radius: float = 1.0):
        """`count` chairs/bins/people-sized objects on free cells, away from a pose."""
        objects = []
        for pose in sample_free_poses(self.map, count * 4, self.rng, clearance=0.5):
            if keep_clear_of is not None and pose.distance_to(keep_clear_of)[0] < clear_radius:
                continue
            kind = self.rng.integers(3)
            size = [(float(self.rng.uniform(0.4, 0.6)), float(self.rng.uniform(0.4, 0.6))),   # chair
                    (float(self.rng.uniform(0.15, 0.25)),),                                  # bin
                    (0.25,)][kind]                                                           # person
            objects.append(ClutterObject(pose.x, pose.y, size, 1.0, pose.yaw))
            if len(objects) == count:
                break
        self.add_clutter(objects)
        return objects

    def laser_pose(self) -> Rigid2D:
        pos, q = p.getLinkState(self.robot, self.laser_link, computeForwardKinematics=True,
                                physicsClientId=self.client)[4:6]
        return Rigid2D(pos[0], pos[1], p.getEulerFromQuaternion(q)[2])

    def scan(self) -> Scan:
        """One scan from the laser's current pose: ranges to the first hit, inf where none,
        Gaussian noise, NaN dropouts."""
        lp = self.laser_pose()
        pos = p.getLinkState(self.robot, self.laser_link, physicsClientId=self.client)[4]
        return self._cast_scan(self.laser, lp.x, lp.y, pos[2], lp.yaw, self.rng)

    def rear_scan(self) -> Scan:
        """One scan of the rear laser (REAR_LASER_MOUNT); the simulator needs `rear_laser`."""
        if self.rear_laser is None:
            raise RuntimeError('this simulator has no rear laser (Simulator(..., rear_laser=LaserConfig()))')
        pos, rot = self._sensor_pose(REAR_LASER_MOUNT)
        return self._cast_scan(self.rear_laser, pos[0], pos[1], pos[2], math.atan2(rot[1, 0], rot[0, 0]),
                               self.rear_rng)

    def lidar_points(self) -> np.ndarray:
        """One revolution of the 3D lidar (LIDAR_MOUNT): (rings, columns, 3) points in the
        lidar frame, lowest ring first, NaN where a ray hit nothing within range_max."""
        cfg = self.lidar
        if cfg is None:
            raise RuntimeError('this simulator has no 3D lidar (Simulator(..., lidar=Lidar3DConfig()))')
        pos, rot = self._sensor_pose(LIDAR_MOUNT)
        directions = cfg.directions().reshape(-1, 3)
        world = directions @ rot.T
        frac = self._cast(pos + cfg.range_min * world, pos + cfg.range_max * world)
        ranges = np.where(np.isfinite(frac), cfg.range_min + frac * (cfg.range_max - cfg.range_min), np.nan)
        if cfg.noise_std > 0:
            ranges = ranges + self.lidar_rng.normal(0.0, cfg.noise_std, ranges.shape)
        return (directions * ranges[:, None]).reshape(cfg.rings, cfg.columns, 3)

    def _sensor_pose(self, mount: Mount3D) -> tuple[np.ndarray, np.ndarray]:
        """A sensor's position and rotation in the world, from the body's pose (pybullet
        keeps it at the centre of mass) and the sensor's mounting on base_link."""
        com, q = p.getBasePositionAndOrientation(self.robot, physicsClientId=self.client)
        body = np.array(p.getMatrixFromQuaternion(q)).reshape(3, 3)
        base = np.asarray(com) - body @ np.array([self.base_T_com.x, self.base_T_com.y, self.com_height])
        return base + body @ np.array([mount.x, mount.y, mount.z]), body @ mount.rotation()

    def _cast(self, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
        """The hit fraction along each ray from starts to ends; inf where it hits nothing."""
        fractions = []
        for i in range(0, len(starts), RAY_BATCH):
            hits = p.rayTestBatch(starts[i:i + RAY_BATCH].tolist(), ends[i:i + RAY_BATCH].tolist(), numThreads=0,
                                  physicsClientId=self.client)
            fractions.extend(h[2] if h[0] >= 0 else np.inf for h in hits)
        return np.array(fractions)

    def _cast_scan(self, cfg: LaserConfig, x: float, y: float, z: float, yaw: float, rng) -> Scan:
        a0, inc, angles = cfg.angles()
        world = yaw + angles
        starts = np.column_stack([x + cfg.range_min * np.cos(world), y + cfg.range_min * np.sin(world),
                                  np.full(len(world), z)])
        ends = np.column_stack([x + cfg.range_max * np.cos(world), y + cfg.range_max * np.sin(world),
                                np.full(len(world), z)])
        frac = self._cast(starts, ends)
        ranges = cfg.corrupt(cfg.range_min + frac * (cfg.range_max - cfg.range_min), rng)
        return Scan(a0, inc, cfg.range_min, cfg.range_max, ranges)
