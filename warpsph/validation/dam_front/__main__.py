"""``python -m warpsph.validation.dam_front``: the case's own command line (``--help``)."""

from warpsph.validation.dam_front import main

if __name__ == "__main__":
    main()
