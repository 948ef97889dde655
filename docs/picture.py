"""Renders docs/assets/robots.png: a frame of the cart-pole, the cube, the TurtleBot in its
maze and the acrobot, each a few random steps after its reset (run from the repository root:
MUJOCO_GL=egl python docs/picture.py)."""
import sys; sys.path.insert(0, ".")
import numpy as np, torch
from PIL import Image
from tasks.catalog import compose
from tasks.factory import build_env
tiles = []
for robot, task in [("cartpole", "stay_up"), ("cube", "one_disk_walk"), ("turtlebot", "maze"), ("acrobot", None)]:
    cfg = compose(robot, task=task) if task else compose(robot)
    env = build_env(cfg, 1, 0)
    td = env.reset()
    for _ in range(5):
        td = env.rand_action(td); td, td2 = env.step_and_maybe_reset(td); td = td2
    img = env.render(width=480, height=360)
    img = img[0] if getattr(img, "ndim", 3) == 4 else img
    tiles.append(np.asarray(img))
    env.close()
Image.fromarray(np.concatenate(tiles, axis=1)).save("docs/assets/robots.png")
print([t.shape for t in tiles])
