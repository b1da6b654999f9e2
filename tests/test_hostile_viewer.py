"""The viewer answers every hostile message with one error line and keeps the websocket open:
property-based tests (hypothesis) of its message check, and the messages that once dropped the
websocket (a 400-digit integer, JSON nested 20,000 deep) sent to a real server."""
import json

import pytest

hypothesis = pytest.importorskip("hypothesis", reason="pip install hypothesis (the test extra)")
pytest.importorskip("starlette", reason="the viewer extra is not installed (pip install '.[viewer]')")
pytest.importorskip("uvicorn", reason="the viewer extra is not installed (pip install '.[viewer]')")
pytest.importorskip("tomli_w", reason="the viewer extra is not installed (pip install '.[viewer]')")
pytest.importorskip("websockets.sync.client", reason="websockets is not installed")
from hypothesis import given, settings, strategies as st

from popvol.errors import PopvolError
from popvol.viewer import settings as S
from popvol.viewer.engine import FULL, Engine
from popvol.viewer.server import MAX_MESSAGE, running

from test_viewer import connect, receive, write_sequence_scene, write_small_scene

HOSTILE = [
    '{"type": "set", "settings": {"density": 1' + "0" * 400 + "}}",
    '{"type": "set", "settings": {"density": 1' + "0" * 5000 + "}}",
    "[" * 20_000 + "]" * 20_000,
    '{"type": "set", "settings": {"density": ' + "[" * 20_000 + "]" * 20_000 + "}}",
    '{"type": ' + "1" * 400 + "}",
    '{"type": "set", "settings": {"' + "x" * 50_000 + '": 1}}',
    '{"type": "' + "y" * 50_000 + '"}',
    '{"type": "save", ' + ", ".join(f'"k{i}": {i}' for i in range(2000)) + "}",
    '{"type": "set", "settings": {"camera_distance": 1e308}}',
    '"\\ud800"',
    "\x00",
    "",
]


def check_one_line(message: str):
    assert "\n" not in message and len(message) <= 1000, message[:300]


@pytest.mark.parametrize("text", HOSTILE)
def test_hostile_messages_are_refused_with_one_line(text):
    try:
        S.parse_message(text, (0.1, 10.0), has_sun=True)
    except PopvolError as e:
        check_one_line(str(e))


json_values = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(min_value=-(10**500), max_value=10**500),
              st.floats(allow_nan=False, allow_infinity=False), st.text(max_size=20)),
    lambda inner: st.one_of(st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=12), inner, max_size=4)),
    max_leaves=15)
setting_names = st.one_of(st.sampled_from(sorted(S.RANGES) + ["frame"]), st.text(max_size=12))
messages = st.one_of(
    json_values,
    st.fixed_dictionaries({"type": st.sampled_from(["set", "save"])},
                          optional={"settings": st.dictionaries(setting_names, json_values, max_size=4),
                                    "extra": json_values}),
    st.fixed_dictionaries({"type": json_values}))


@settings(max_examples=200, deadline=None, derandomize=True)
@given(messages, st.booleans(), st.booleans(), st.sampled_from([None, [1, 3, 5], [0, 1, 2, 10]]))
def test_any_json_message_is_accepted_or_refused_with_one_line(msg, has_sun, has_key, frames):
    text = json.dumps(msg)
    try:
        m = S.parse_message(text, (0.1, 10.0), has_sun=has_sun, has_key=has_key, frames=frames)
    except PopvolError as e:
        check_one_line(str(e))
        return
    assert m.kind in ("set", "save")
    for name, v in m.changes.items():
        if name == "frame":
            assert frames is not None and type(v) is int and v in frames
        else:
            assert name in S.RANGES and isinstance(v, float)


#: Hostile frames for the sequence of frames 1, 3, 5 (JSON text of the value).
HOSTILE_FRAMES = ["-1", "1e400", '"a"', "7", "2", "3.5", "true", "null", "[3]", "1" + "0" * 400, "-1e400",
                  "4.000000001"]


@pytest.mark.parametrize("value", HOSTILE_FRAMES)
def test_hostile_frames_are_refused_with_one_line(value):
    text = '{"type": "set", "settings": {"frame": ' + value + "}}"
    with pytest.raises(PopvolError) as e:
        S.parse_message(text, (0.1, 10.0), has_sun=True, frames=[1, 3, 5])
    check_one_line(str(e.value))
    assert "must be one of the scene's frames (1-5:2)" in str(e.value)
    with pytest.raises(PopvolError, match="this scene has no frames"):
        S.parse_message(text, (0.1, 10.0), has_sun=True, frames=None)


@settings(max_examples=200, deadline=None, derandomize=True)
@given(st.one_of(st.text(max_size=300), st.binary(max_size=100)))
def test_any_text_is_accepted_or_refused_with_one_line(text):
    try:
        S.parse_message(text, (0.1, 10.0), has_sun=True)
    except PopvolError as e:
        check_one_line(str(e))


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    scene = write_small_scene(tmp_path_factory.mktemp("hostile-viewer"))
    engine = Engine(scene, resolution=12, draft_resolution=8)
    with running(engine, tmp_path_factory.mktemp("saves"), refine_delay=0.1) as url:
        yield url


def test_server_answers_every_hostile_message_and_stays_up(server):
    with connect(server) as ws:
        receive(ws, "frame")
        for text in HOSTILE:
            assert len(text.encode()) <= MAX_MESSAGE
            ws.send(text)
            error = receive(ws, "error", timeout=30)["message"]
            check_one_line(error)
            assert "internal error" not in error, error
        ws.send(json.dumps({"type": "set", "settings": {"g": 0.3}}))
        frame = receive(ws, "frame", level=FULL)
        assert frame["settings"]["g"] == 0.3


@pytest.fixture(scope="module")
def seq_server(tmp_path_factory):
    scene = write_sequence_scene(tmp_path_factory.mktemp("hostile-seq"))
    engine = Engine(scene, resolution=12, draft_resolution=8)
    with running(engine, tmp_path_factory.mktemp("saves"), refine_delay=0.1) as url:
        yield url


def test_sequence_server_answers_hostile_frames_and_stays_up(seq_server):
    with connect(seq_server) as ws:
        receive(ws, "frame")
        for value in HOSTILE_FRAMES:
            ws.send('{"type": "set", "settings": {"frame": ' + value + "}}")
            error = receive(ws, "error", timeout=30)["message"]
            check_one_line(error)
            assert "must be one of the scene's frames" in error, error
        ws.send(json.dumps({"type": "set", "settings": {"frame": 5}}))
        frame = receive(ws, "frame", level=FULL)
        assert frame["frame"] == 5 and frame["version"] == 1        # none of the hostile ones counted
