"""The one exception type the CLI turns into a one-line message and exit code 2."""


class UserError(Exception):
    """Bad input from the user: a file, a field, an option.

    The message names the file and the field; the CLI prints it on one line
    and exits with code 2, without a traceback.
    """
