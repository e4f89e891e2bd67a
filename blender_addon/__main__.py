"""``python -m blender_addon SCENE.blend [options]``: see :mod:`.cli`."""

import sys

from .cli import main

sys.exit(main())
