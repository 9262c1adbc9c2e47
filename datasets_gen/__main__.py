"""``python -m datasets_gen CONFIG --out DIR [--workers N | --scheduler ADDRESS|local:N] [--seed S]``,
or ``python -m datasets_gen export DIR --format webdataset|parquet --out OUT`` (shards)."""

import sys

if __name__ == "__main__":
    if sys.argv[1:2] == ["export"]:
        from .export import main as export_main

        sys.exit(export_main(sys.argv[2:]))
    from .runner import main

    sys.exit(main())
