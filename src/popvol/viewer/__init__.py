"""``popvol view``: an interactive viewer in the browser (see docs/VIEWER.md).

- :mod:`.settings`: the controls' state, checking the page's messages, settings -> scene/TOML;
- :mod:`.engine`: frames from settings, propagating only when light or medium changed; a
  sequence's frames (loaded per frame, the last few kept, keyframes under the controls);
- :mod:`.server`: the Starlette app (page, static files, websocket) and ``serve``;
- ``static/``: the page (plain HTML, CSS and JavaScript, no build step).

Needs the ``viewer`` extra (``pip install 'popvol[viewer]'``).
"""
