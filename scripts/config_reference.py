"""Write the configuration reference, docs/reference/configuration.md, from the configuration dataclasses' fields and
docstrings (:mod:`tools.reference.configuration`); run it after a field, a default or a docstring changes::

    .venv/bin/python scripts/config_reference.py            # write the page
    .venv/bin/python scripts/config_reference.py --check    # exit 1 if the page is out of date
"""

from __future__ import annotations

import argparse
import sys

from tools.reference.configuration import PAGE, ROOT, check, write


def main(check_only: bool) -> int:
    if check_only:
        stale = check(ROOT / PAGE)
        print(stale or f"{PAGE} is up to date")
        return 1 if stale else 0
    print(f"wrote {write(ROOT / PAGE).relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="only check that the page is up to date")
    sys.exit(main(parser.parse_args().check))
