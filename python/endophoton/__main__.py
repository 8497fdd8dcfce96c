import sys

from .cli import main

if __name__ == "__main__":  # not when a spawned Dask worker re-imports it
    sys.exit(main())
