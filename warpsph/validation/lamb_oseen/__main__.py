"""``python -m warpsph.validation.lamb_oseen``: the case's own command line (``--help``)."""

from warpsph.validation.lamb_oseen import main

if __name__ == "__main__":
    main()
