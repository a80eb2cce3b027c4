import sys

from bench.realdata.run import main

sys.exit(main())
