import sys

from irdetect.cli import main

sys.exit(main())
