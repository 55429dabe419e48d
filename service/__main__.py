"""``python -m sdcnet.service``: the same as ``sdc-serve``."""

import sys

from sdcnet.service.launch import main

sys.exit(main())
