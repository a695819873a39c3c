"""One exception family: every error the project raises on purpose derives from `UwsimnetError`.

The `uwsimnet` command catches the base once (cli/main.py) and prints the message as one line with exit code
2 (scene errors read `file:line: message`); anything else is a bug and keeps its traceback.  The subclasses
that are also ValueError/RuntimeError/OSError keep those bases, so callers that caught the builtin still do.
The wire (`uwsimnet_gli.wire`) is not in this family: the client package never imports the simulator."""


class UwsimnetError(Exception):
    """The base: a refusal or a failure the user can act on, said in one line."""


class UserError(UwsimnetError):
    """A problem with the user's input (a file, an option, a name): printed as one line, exit code 2."""
