"""``python -m depthguard`` runs the ``depthguard`` command."""

from depthguard.cli import main

if __name__ == "__main__":
    main()
