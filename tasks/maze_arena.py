"""A maze of walls drawn as a grid of characters, and the arena built from it.

Each string of ``layout`` is one row of square cells of ``cell_size`` metres,
the first row northmost (+y), the maze centred on the origin:

- ``#`` a wall cell;
- ``.`` or a space: free floor;
- ``>`` ``^`` ``<`` ``v``: free floor where an episode may start, heading east
  (+x), north (+y), west or south.

Wall cells merge into as few boxes as a greedy scan finds (fewer geoms, cheaper
laser rays). The arena adds a top-down camera, ``top``, that sees the whole maze.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from dm_control import mjcf

from tasks.arena import floor_arena
from tasks.base import require

_HEADINGS = {">": 0.0, "^": math.pi / 2, "<": math.pi, "v": -math.pi / 2}
_FREE = {".", " "} | set(_HEADINGS)


@dataclass(frozen=True)
class Maze:
    """A parsed layout: wall boxes and start poses, in metres."""

    walls: tuple[tuple[float, float, float, float], ...]  # (x, y, half_x, half_y)
    starts: np.ndarray  # (n, 3): x, y, yaw
    width: float  # x extent
    depth: float  # y extent

    @classmethod
    def parse(cls, layout: Sequence[str], cell_size: float) -> "Maze":
        require(cell_size > 0, "task.cell_size must be > 0", cell_size)
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
                while r1 + 1 < nr and wall[r1 + 1, c:c1 + 1].all() and not taken[r1 + 1, c:c1 + 1].any():
                    r1 += 1
                taken[r:r1 + 1, c:c1 + 1] = True
                x, y = centre((r + r1) / 2, (c + c1) / 2)
                boxes.append((x, y, (c1 - c + 1) * cell_size / 2, (r1 - r + 1) * cell_size / 2))
        return cls(tuple(boxes), np.array(starts), nc * cell_size, nr * cell_size)


def maze_arena(name: str, maze: Maze, timestep: float, wall_height: float = 0.5) -> mjcf.RootElement:
    """A floor with ``maze``'s walls (brick red) and a top-down camera ``top``."""
    require(wall_height > 0, "task.wall_height must be > 0", wall_height)
    arena = floor_arena(name, timestep, size=max(maze.width, maze.depth) / 2 + 1.0)
    arena.asset.add("material", name="brick", rgba=[0.7, 0.33, 0.22, 1])
    for i, (x, y, hx, hy) in enumerate(maze.walls):
        arena.worldbody.add("geom", name=f"wall_{i}", type="box", pos=[x, y, wall_height / 2],
                            size=[hx, hy, wall_height / 2], material="brick")
    # Looking straight down, +x to the right; frames the maze at a 4:3 aspect.
    fovy = 45.0
    half = max(maze.depth / 2, maze.width / 2 / (4 / 3)) * 1.08
    height = half / math.tan(math.radians(fovy / 2)) + wall_height
    arena.worldbody.add("camera", name="top", pos=[0, 0, height], xyaxes=[1, 0, 0, 0, 1, 0],
                        fovy=fovy)
    return arena
