"""``python -m sdcnet.client``: the same as ``sdc-client``."""

import sys

from sdcnet.client.cli import main

sys.exit(main())
