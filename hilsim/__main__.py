import sys

from hilsim.cli import main

sys.exit(main())
