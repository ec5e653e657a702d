"""``python -m warpsph.validation.taylor_green``: the case's own command line (``--help``)."""

from warpsph.validation.taylor_green import main

if __name__ == "__main__":
    main()
