"""``python -m octofuse.cli``: the ``octofuse`` command."""

import sys

from . import main

sys.exit(main())
