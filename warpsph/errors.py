"""Errors that warpsph raises on user input."""


class SceneError(ValueError):
    """A scene file (or a file it names) is invalid; the message names the file and the key path.
    ``file`` "" is a command-line option alone (key "--frames").

    Example:

    ```python
    import warpsph

    try:
        warpsph.scene_from_dict({"particle_radius": -0.02, "domain": {"min": [0, 0, 0], "max": [1, 1, 1]}})
    except warpsph.SceneError as error:
        print(error)  # <dict>: particle_radius: ... (error.file, error.key, error.reason)
    ```
    """

    def __init__(self, file, key, message):
        self.file = str(file) if file is not None else "<scene>"
        self.key = key
        self.reason = message
        where = ": ".join(part for part in (self.file, key) if part)
        super().__init__(f"{where}: {message}")
