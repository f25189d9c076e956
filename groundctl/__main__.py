import sys

from groundctl.cli import main

sys.exit(main())
