"""Errors that warpsph raises on user input."""


class SceneError(ValueError):
    """A scene file (or a file it names) is invalid; the message names the file and the key path.
    ``file`` "" is a command-line option alone (key "--frames")."""

    def __init__(self, file, key, message):
        self.file = str(file) if file is not None else "<scene>"
        self.key = key
        self.reason = message
        where = ": ".join(part for part in (self.file, key) if part)
        super().__init__(f"{where}: {message}")
