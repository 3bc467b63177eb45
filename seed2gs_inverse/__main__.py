"""``python -m seed2gs_inverse``: the ``seed2gs`` command (:func:`seed2gs_inverse.cli.main`)."""

import sys

from .cli import main

sys.exit(main())
