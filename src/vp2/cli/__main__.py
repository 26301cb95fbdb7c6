"""``python -m vp2.cli``: the same as the ``vp2`` command."""

import sys

from vp2.cli import main

sys.exit(main())
