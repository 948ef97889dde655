"""Arenas: the world a task builds around its robot (floor, light, cameras)."""

from __future__ import annotations

from dm_control import mjcf


def floor_arena(name: str, timestep: float, size: float = 5.0) -> mjcf.RootElement:
    """A lit, checkered floor at z = 0; offscreen rendering up to 1920 x 1080."""
    if not timestep > 0:
        raise ValueError(f"physics timestep must be > 0, got {timestep}")
    arena = mjcf.RootElement(model=name)
    arena.compiler.angle = "radian"
    arena.option.timestep = timestep
    # implicitfast treats actuator damping (velocity servos) implicitly: stiff
    # servo gains stay stable at millisecond timesteps.
    arena.option.integrator = "implicitfast"
    arena.visual.headlight.ambient = [0.4, 0.4, 0.4]
    arena.visual.headlight.diffuse = [0.6, 0.6, 0.6]
    arena.visual.quality.shadowsize = 2048
    # Offscreen frames up to full HD (MuJoCo's default buffer is 640 x 480).
    offscreen = getattr(arena.visual, "global")
    offscreen.offwidth, offscreen.offheight = 1920, 1080
    arena.asset.add(
        "texture", name="grid", type="2d", builtin="checker", width=512, height=512,
        rgb1=[0.2, 0.3, 0.4], rgb2=[0.1, 0.2, 0.3],
    )
    arena.asset.add(
        "material", name="grid", texture="grid", texrepeat=[8, 8], reflectance=0.1
    )
    arena.asset.add(
        "texture", name="sky", type="skybox", builtin="gradient", width=256, height=256,
        rgb1=[0.4, 0.6, 0.8], rgb2=[0.0, 0.0, 0.0],
    )
    arena.worldbody.add("light", name="sun", pos=[0, 0, 6], dir=[0, 0, -1], directional=True)
    arena.worldbody.add(
        "geom", name="floor", type="plane", size=[size, size, 0.1], material="grid"
    )
    return arena
