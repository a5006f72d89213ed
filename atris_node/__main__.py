"""``python -m atris_node`` runs the ``atris`` command."""

import sys

from atris_node.cli import main

sys.exit(main())
