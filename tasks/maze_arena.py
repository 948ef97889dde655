"""Mazes of brick walls, and the arena built around one.

Two ways to describe a maze, both centred on the origin:

- :meth:`Maze.ring`: a round loop, the corridor between two circles of wall
  (each a polygon of ``segments`` boxes); ``starts`` start poses evenly spaced on
  the corridor's centre line, alternately heading anticlockwise and clockwise.
- :meth:`Maze.grid`: a grid of characters, one string per row of square cells of
  ``cell_size`` metres, the first row northmost (+y): ``#`` wall, ``.`` or a space
  free floor, ``>`` ``^`` ``<`` ``v`` free floor where an episode may start,
  heading east (+x), north (+y), west or south. Wall cells merge into as few
  boxes as a greedy scan finds (fewer geoms, cheaper laser rays).

:func:`maze_arena` adds the walls to a floor with a top-down camera, ``top``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from dm_control import mjcf

from tasks.arena import floor_arena
from params import finite, require, whole

_HEADINGS = {">": 0.0, "^": math.pi / 2, "<": math.pi, "v": -math.pi / 2}
_FREE = {".", " "} | set(_HEADINGS)


@dataclass(frozen=True)
class Maze:
    """Wall boxes and start poses, in metres and radians."""

    walls: tuple[tuple[float, float, float, float, float], ...]  # x, y, half_x, half_y, yaw
    starts: np.ndarray  # (n, 3): x, y, yaw
    half_extent: float  # the maze fits in [-half_extent, half_extent]^2

    @classmethod
    def ring(cls, inner_radius: float, outer_radius: float, segments: int = 24,
             starts: int = 8, wall_thickness: float = 0.2) -> "Maze":
        require(finite(inner_radius) and inner_radius > 0,
                "task.ring.inner_radius must be a finite number > 0", inner_radius)
        require(finite(outer_radius), "task.ring.outer_radius must be a finite number", outer_radius)
        require(inner_radius < outer_radius,
                f"task.ring.outer_radius must be > task.ring.inner_radius ({inner_radius}): "
                f"the ring needs 0 < inner_radius < outer_radius", outer_radius)
        require(whole(segments) and segments >= 8, "task.ring.segments must be an integer >= 8",
                segments)
        require(whole(starts) and starts >= 1, "task.ring.starts must be an integer >= 1", starts)
        require(finite(wall_thickness) and wall_thickness > 0,
                "task.ring.wall_thickness must be a finite number > 0", wall_thickness)
        segments, starts = int(segments), int(starts)
        walls = []
        for radius, outward in ((inner_radius, -1.0), (outer_radius, 1.0)):
            # Each box's face towards the corridor lies on the polygon's edge at ``radius``.
            half_length = radius * math.tan(math.pi / segments) + 0.01
            centre = radius + outward * wall_thickness / 2
            for i in range(segments):
                a = 2 * math.pi * (i + 0.5) / segments
                walls.append((centre * math.cos(a), centre * math.sin(a),
                              wall_thickness / 2, half_length, a))
        mid = (inner_radius + outer_radius) / 2
        angles = 2 * math.pi * np.arange(starts) / starts
        turn = np.where(np.arange(starts) % 2 == 0, math.pi / 2, -math.pi / 2)
        poses = np.stack([mid * np.cos(angles), mid * np.sin(angles), angles + turn], axis=1)
        return cls(tuple(walls), poses, outer_radius + wall_thickness)

    @classmethod
    def grid(cls, layout: Sequence[str], cell_size: float) -> "Maze":
        require(finite(cell_size) and cell_size > 0, "task.cell_size must be a finite number > 0",
                cell_size)
        rows = [str(r) for r in layout]
        require(len(rows) > 0 and all(len(r) == len(rows[0]) > 0 for r in rows),
                "task.layout must be a non-empty list of strings of equal length", rows)
        bad = {ch for r in rows for ch in r} - _FREE - {"#"}
        require(not bad, "task.layout may only hold '#', '.', ' ', '>', '^', '<', 'v'",
                "".join(sorted(bad)))
        nr, nc = len(rows), len(rows[0])

        def centre(r: float, c: float) -> tuple[float, float]:
            return (c - (nc - 1) / 2) * cell_size, ((nr - 1) / 2 - r) * cell_size

        starts = [(*centre(r, c), _HEADINGS[ch])
                  for r, row in enumerate(rows) for c, ch in enumerate(row) if ch in _HEADINGS]
        require(len(starts) > 0, "task.layout needs at least one start cell (> ^ < v)", rows)
        wall = np.array([[ch == "#" for ch in row] for row in rows])
        taken = np.zeros_like(wall)
        boxes = []
        for r in range(nr):
            for c in range(nc):
                if not wall[r, c] or taken[r, c]:
                    continue
                c1 = c
                while c1 + 1 < nc and wall[r, c1 + 1] and not taken[r, c1 + 1]:
                    c1 += 1
                r1 = r
                while (r1 + 1 < nr and wall[r1 + 1, c:c1 + 1].all()
                       and not taken[r1 + 1, c:c1 + 1].any()):
                    r1 += 1
                taken[r:r1 + 1, c:c1 + 1] = True
                x, y = centre((r + r1) / 2, (c + c1) / 2)
                half_x, half_y = (c1 - c + 1) * cell_size / 2, (r1 - r + 1) * cell_size / 2
                boxes.append((x, y, half_x, half_y, 0.0))
        return cls(tuple(boxes), np.array(starts), max(nr, nc) * cell_size / 2)


def maze_arena(name: str, maze: Maze, timestep: float,
               wall_height: float = 0.5) -> mjcf.RootElement:
    """A floor with ``maze``'s walls (brick red) and a top-down camera ``top``."""
    require(wall_height > 0, "task.wall_height must be > 0", wall_height)
    arena = floor_arena(name, timestep, size=maze.half_extent + 1.0)
    arena.asset.add("material", name="brick", rgba=[0.7, 0.33, 0.22, 1])
    for i, (x, y, hx, hy, yaw) in enumerate(maze.walls):
        arena.worldbody.add("geom", name=f"wall_{i}", type="box", pos=[x, y, wall_height / 2],
                            size=[hx, hy, wall_height / 2], euler=[0, 0, yaw], material="brick")
    # Looking straight down with +x to the right, the whole maze in view.
    fovy = 45.0
    height = maze.half_extent * 1.08 / math.tan(math.radians(fovy / 2)) + wall_height
    arena.worldbody.add("camera", name="top", pos=[0, 0, height], xyaxes=[1, 0, 0, 0, 1, 0],
                        fovy=fovy)
    return arena
