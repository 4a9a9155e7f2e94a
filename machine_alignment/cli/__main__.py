import sys

from machine_alignment.cli import main

sys.exit(main())
