"""Where a robot's model file is looked up (no MuJoCo import: the catalog reads it)."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

#: Config folders a relative ``model`` path is looked up in, after the working folder; the
#: shipped ``conf/`` first (``tasks.catalog`` adds a user's config folders). A run's config
#: holds the absolute path (``tasks.catalog.locate_model``): this serves other compositions.
MODEL_FOLDERS: list[Path] = [Path(str(resources.files("conf")))]
