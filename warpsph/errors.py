"""Errors that warpsph raises on user input."""


class SceneError(ValueError):
    """A scene file (or a file it names) is invalid; the message names the file and the key path."""

    def __init__(self, file, key, message):
        self.file = str(file) if file is not None else "<scene>"
        self.key = key
        self.reason = message
        where = f"{self.file}: {key}" if key else self.file
        super().__init__(f"{where}: {message}")
