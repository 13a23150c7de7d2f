"""``python -m facecapges``: the command line (:func:`facecapges.commands.cli.main`)."""

from facecapges.commands.cli import main

if __name__ == "__main__":
    main()
