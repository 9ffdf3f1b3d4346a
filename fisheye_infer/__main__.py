import sys

from fisheye_infer.cli import main

sys.exit(main())
