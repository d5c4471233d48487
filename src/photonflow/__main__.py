"""``python -m photonflow``: the same as the ``photonflow`` command."""

from .cli import main

if __name__ == "__main__":
    main()
