"""``python -m warpsph.validation.hydrostatic``: the case's own command line (``--help``)."""

from warpsph.validation.hydrostatic import main

if __name__ == "__main__":
    main()
