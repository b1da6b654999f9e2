"""The one exception popvol raises for bad input.

Every message is a single line that names the file or field at fault and the allowed range,
e.g. ``scene.toml: medium.albedo = 1.5 is outside [0, 1]``. The CLI prints it without a
traceback and exits with status 2.
"""


class PopvolError(ValueError):
    """Invalid input (scene, volume file, option). The message is meant for the user."""
