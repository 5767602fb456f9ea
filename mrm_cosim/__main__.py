"""``python -m mrm_cosim``: the ``mrm`` command."""

import sys

from mrm_cosim.mrm.cli import main

sys.exit(main())
