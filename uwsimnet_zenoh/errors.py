"""The error a command reports as one line with exit code 2 (`uwsimnet`'s `main` catches it).

Its own module, not cli/: the sub-commands raise it, and `python -m uwsimnet_zenoh.cli` runs cli as
`__main__`, a second copy of that module whose class would not match theirs."""


class UserError(Exception):
    """A problem with the user's input: printed as one line, exit code 2."""
