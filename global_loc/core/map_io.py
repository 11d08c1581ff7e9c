"""Occupancy maps: loading a nav2_map_server map (YAML + image) or OccupancyGrid fields
into one type, `OccupancyMap`, with nav2's semantics and a clear MapError for every
malformed input. `occupancy[row, col]` is in image order (row 0 = the largest y), 100
occupied, 0 free, -1 unknown (`scale` mode: 0..100); where the cells are in the world is
the map's GridFrame (core/grid_frame.py).
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Optional

import cv2
import numpy as np
import yaml

from .files import UnreadableFile, brief, not_a_regular_file, read_yaml_file
from .grid_frame import GridFrame
from .limits import MAP_RESOLUTION_M, MAX_MAP_CELLS
from .transform import Rigid2D

OCCUPIED = 100
FREE = 0
UNKNOWN = -1


class MapError(ValueError):
    """A map could not be loaded or is malformed; the message names the file and the problem."""


def occupied_cells(occupancy: np.ndarray) -> np.ndarray:
    """Where occupancy values (100 / 0 / -1, or a 0..100 scale) mean an occupied cell."""
    return occupancy >= 65


def free_cells(occupancy: np.ndarray) -> np.ndarray:
    """Where occupancy values mean a free cell (the rest of the known, between the two
    thresholds, and -1 are unknown)."""
    return (occupancy >= 0) & (occupancy < 35)


@dataclass
class OccupancyMap:
    occupancy: np.ndarray          # int8 (H, W), image row order, 100 / 0 / -1
    frame: GridFrame               # where the cells are (resolution, size, origin)
    source: str = '<array>'

    @property
    def resolution(self) -> float:
        return self.frame.resolution

    @property
    def origin(self) -> Rigid2D:
        return self.frame.origin

    @property
    def height(self) -> int:
        return self.frame.height        # make_map sizes the frame by the grid

    @property
    def width(self) -> int:
        return self.frame.width

    @property
    def diagonal_m(self) -> float:
        """The map's diagonal: no two points of it lie farther apart."""
        return math.hypot(self.width, self.height) * self.resolution

    @property
    def occupied(self) -> np.ndarray:
        """Boolean mask of occupied cells."""
        return occupied_cells(self.occupancy)

    @property
    def free(self) -> np.ndarray:
        return free_cells(self.occupancy)

    @property
    def unknown(self) -> np.ndarray:
        """Boolean mask of cells the map says nothing about (neither occupied nor free)."""
        return ~(self.occupied | self.free)

    def is_free_at(self, xy) -> np.ndarray:
        """True where the world points fall on free cells inside the map."""
        cells = self.frame.cell_of(xy)
        inside = self.frame.contains(cells)
        out = np.zeros(len(cells), dtype=bool)
        out[inside] = self.free[cells[inside, 1], cells[inside, 0]]
        return out

    def open_unknown(self) -> np.ndarray:
        """Boolean mask of the unknown cells a beam can reach through free space: the
        8-connected regions of unknown cells that touch a free cell (a part of the place
        never mapped, seen through a frontier). An unknown region closed off by occupied
        cells - the outside of a walled building, the inside of a thick wall - is left out:
        a beam reaches it only through a mapped wall."""
        unknown = self.unknown.astype(np.uint8)
        if not unknown.any():
            return unknown.astype(bool)
        count, labels = cv2.connectedComponents(unknown, connectivity=8)
        touching = cv2.dilate(self.free.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        open_labels = np.zeros(count, bool)
        open_labels[np.unique(labels[touching & (unknown > 0)])] = True
        open_labels[0] = False          # label 0: the known cells
        return open_labels[labels]

    def distance_to_occupied(self, also: Optional[np.ndarray] = None) -> np.ndarray:
        """float32 (H, W): each cell's distance in cells to the nearest occupied cell, or
        cell of `also` (a mask: where a wall may stand for all the map says) - 1e6
        everywhere on a map without one."""
        target = self.occupied | also if also is not None else self.occupied
        if not target.any():
            return np.full(self.occupancy.shape, 1e6, np.float32)
        return cv2.distanceTransform((~target).astype(np.uint8), cv2.DIST_L2, 5)

    def surface_image(self) -> np.ndarray:
        """uint8 image, 255 on occupied cells that touch a free cell (8-neighbourhood):
        the wall surfaces a laser can hit. A scan's local map shows one-cell surfaces, not
        the walls' thickness, so image matchers compare like with like against this."""
        free_nearby = cv2.dilate(self.free.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        return np.where(self.occupied & free_nearby, 255, 0).astype(np.uint8)


def make_map(occupancy: np.ndarray, resolution: float, origin: Rigid2D, source: str = '<array>') -> OccupancyMap:
    """An OccupancyMap from an int8 grid in image row order."""
    return OccupancyMap(occupancy, GridFrame(resolution, occupancy.shape[1], occupancy.shape[0], origin), source)


def from_occupancy_grid(width, height, resolution, origin, data, source='<OccupancyGrid>') -> OccupancyMap:
    """From nav_msgs/OccupancyGrid fields: `data` row-major from the *bottom* row, values
    -1..100; `origin` an (x, y, yaw) tuple or Rigid2D."""
    try:
        width, height, resolution = int(width), int(height), float(resolution)
    except (TypeError, ValueError) as e:
        raise MapError(f'{source}: bad width/height/resolution: {e}') from None
    if width <= 0 or height <= 0:
        raise MapError(f'{source}: empty grid ({width} x {height})')
    check_resolution(resolution, source)
    check_cells(width, height, source)
    grid = np.asarray(data)
    if grid.size != width * height:
        raise MapError(f'{source}: data has {grid.size} cells, expected {width} x {height} = {width * height}')
    grid = grid.astype(np.int16).reshape(height, width)
    if grid.min() < -1 or grid.max() > 100:
        raise MapError(f'{source}: cell values must lie in -1..100')
    try:
        origin = origin.as_tuple() if isinstance(origin, Rigid2D) else tuple(float(v) for v in origin)
    except (TypeError, ValueError) as e:
        raise MapError(f'{source}: bad origin: {e}') from None
    origin = Rigid2D(*check_origin(origin, source))
    return make_map(np.flipud(grid).astype(np.int8), resolution, origin, source)


def check_resolution(resolution: float, source: str) -> float:
    """The cell size if it lies in limits.MAP_RESOLUTION_M; MapError otherwise (a cell of
    1e-8 m makes bnb divide by zero, one of 1e-6 m a huge search - every goal would fail)."""
    lo, hi = MAP_RESOLUTION_M
    if not (math.isfinite(resolution) and resolution > 0):
        raise MapError(f'{source}: resolution must be a positive number, got {resolution}')
    if not lo <= resolution <= hi:
        why = 'a cell finer than any laser resolves' if resolution < lo else 'one cell would hold a whole room'
        raise MapError(f'{source}: resolution {resolution:g} m is outside [{lo:g}, {hi:g}] m ({why})')
    return resolution


def check_cells(width: int, height: int, source: str) -> None:
    """MapError for a map of more than limits.MAX_MAP_CELLS cells (its precomputation
    would take gigabytes), checked before its cells are copied or converted."""
    if width * height > MAX_MAP_CELLS:
        raise MapError(f'{source}: {width} x {height} = {width * height} cells, more than the {MAX_MAP_CELLS} a '
                       f'map may have (bnb precomputes ~23 bytes a cell); crop it or use a coarser resolution')


def check_origin(origin, source: str):
    """The map origin (x, y, yaw) if it has three values, every one finite; MapError
    otherwise (a NaN origin would put every pose the matchers return at NaN)."""
    if len(origin) != 3:
        raise MapError(f'{source}: origin must be [x, y, yaw], got {brief(list(origin))}')
    if not all(math.isfinite(v) for v in origin):
        raise MapError(f'{source}: origin must be finite numbers (x, y, yaw), got {brief(list(origin))}')
    return origin


def check_regular_file(path: str, source: str, what: str) -> None:
    """MapError unless `path` is a readable regular file (or a symlink to one), saying
    what it is instead: missing, a dangling symlink, a symlink loop, a directory, a FIFO
    (opening one would block), a device or a socket - not just "not found"."""
    prefix = f'{source}: {what}' if what != source else source
    problem = not_a_regular_file(path)
    if problem:
        raise MapError(f'{prefix} {problem}')


def _require(doc, key, path):
    if key not in doc:
        raise MapError(f'{path}: missing key {key!r}')
    return doc[key]


@dataclass(frozen=True)
class _MapYaml:
    image_path: str
    resolution: float
    origin: list
    negate: int
    occupied_thresh: float
    free_thresh: float
    mode: str


def _read_map_yaml(path: str) -> _MapYaml:
    """The YAML's parameters, each checked, the image's path resolved against the YAML's folder."""
    check_regular_file(path, path, 'map YAML')
    try:
        doc = read_yaml_file(path)
    except UnreadableFile as e:
        raise MapError(f'{path}: {e}') from None
    if not isinstance(doc, dict):
        raise MapError(f'{path}: expected a mapping of map parameters, got {type(doc).__name__}')
    image_name = _require(doc, 'image', path)
    if not isinstance(image_name, str) or not image_name:
        raise MapError(f'{path}: key "image" must be a file name')
    try:
        resolution = float(_require(doc, 'resolution', path))
        origin = [float(v) for v in _require(doc, 'origin', path)]
        negate = int(doc.get('negate', 0))
        occ_th = float(_require(doc, 'occupied_thresh', path))
        free_th = float(_require(doc, 'free_thresh', path))
    except MapError:
        raise
    except (TypeError, ValueError) as e:
        raise MapError(f'{path}: bad value: {brief(str(e), 200)}') from None
    mode = doc.get('mode', 'trinary')
    check_resolution(resolution, path)
    check_origin(origin, path)
    if not (0.0 <= free_th < occ_th <= 1.0):
        raise MapError(f'{path}: need 0 <= free_thresh < occupied_thresh <= 1, '
                       f'got free_thresh={free_th}, occupied_thresh={occ_th}')
    if negate not in (0, 1):
        raise MapError(f'{path}: negate must be 0 or 1, got {brief(negate)}')
    if mode not in ('trinary', 'scale', 'raw'):
        raise MapError(f'{path}: mode must be trinary, scale or raw, got {brief(mode)}')
    image_path = image_name if os.path.isabs(image_name) else \
        os.path.join(os.path.dirname(os.path.abspath(path)), image_name)
    return _MapYaml(image_path, resolution, origin, negate, occ_th, free_th, mode)


def _read_shade(image_path: str, path: str) -> tuple[np.ndarray, Optional[np.ndarray]]:
    """The image as nav2 reads it: (grey shade 0..255 as float, alpha channel or None)."""
    check_regular_file(image_path, path, f'image {image_path}')
    image = cv2.imread(image_path, cv2.IMREAD_UNCHANGED)
    if image is None or image.size == 0:
        raise MapError(f'{path}: image {image_path} could not be read')
    check_cells(image.shape[1], image.shape[0], path)    # before the per-cell float conversions below
    if image.dtype != np.uint8:   # 16-bit PGM/PNG: scale to 8 bits as map_server's 0..255 shade
        image = (image.astype(np.float64) / np.iinfo(image.dtype).max * 255.0).round().astype(np.uint8)
    if image.ndim == 3:
        alpha = image[:, :, 3] if image.shape[2] == 4 else None
        return image[:, :, :3].mean(axis=2), alpha   # nav2: colour channels averaged
    return image.astype(np.float64), None


def _occupancy(shade: np.ndarray, alpha: Optional[np.ndarray], y: _MapYaml) -> np.ndarray:
    """Occupancy values (int16: 0 free, 100 occupied, -1 unknown, scale: between) by `y.mode`."""
    if y.mode == 'raw':
        grid = shade.round().astype(np.int16)
        grid[grid > 100] = UNKNOWN
        return grid
    occ = shade / 255.0 if y.negate else (255.0 - shade) / 255.0
    grid = np.full(shade.shape, UNKNOWN, dtype=np.int16)
    grid[occ > y.occupied_thresh] = OCCUPIED
    grid[occ < y.free_thresh] = FREE
    if y.mode == 'scale':
        mid = (occ >= y.free_thresh) & (occ <= y.occupied_thresh)
        grid[mid] = np.rint(99.0 * (occ[mid] - y.free_thresh) / (y.occupied_thresh - y.free_thresh)).astype(np.int16)
        if alpha is not None:
            grid[alpha < 255] = UNKNOWN
    return grid


def load_map_yaml(path) -> OccupancyMap:
    """Load a nav2_map_server map (YAML + PGM/PNG/...), with its semantics: `image`
    relative to the YAML, `negate`, `occupied_thresh`, `free_thresh`, `mode`
    (trinary | scale | raw), `origin` [x, y, yaw]; colour images are averaged to grey."""
    path = os.fspath(path)
    y = _read_map_yaml(path)
    shade, alpha = _read_shade(y.image_path, path)
    return make_map(_occupancy(shade, alpha, y).astype(np.int8), y.resolution, Rigid2D(*y.origin), path)


def save_map_yaml(occupancy_map: OccupancyMap, yaml_path, image_name=None) -> None:
    """Write a trinary nav2 map (PGM, 0 occupied / 254 free / 205 unknown) and its YAML, with
    nav2's usual thresholds (205 reads as (255 - 205) / 255 = 0.196..., just above free_thresh)."""
    yaml_path = os.fspath(yaml_path)
    image_name = image_name or os.path.splitext(os.path.basename(yaml_path))[0] + '.pgm'
    occ = occupancy_map.occupancy
    img = np.full(occ.shape, 205, dtype=np.uint8)
    img[occupancy_map.free] = 254
    img[occupancy_map.occupied] = 0
    cv2.imwrite(os.path.join(os.path.dirname(os.path.abspath(yaml_path)), image_name), img)
    o = occupancy_map.origin
    with open(yaml_path, 'w') as f:
        yaml.safe_dump({'image': image_name, 'mode': 'trinary', 'resolution': occupancy_map.resolution,
                        'origin': [float(o.x), float(o.y), float(o.yaw)], 'negate': 0,
                        'occupied_thresh': 0.65, 'free_thresh': 0.196}, f, sort_keys=False)
