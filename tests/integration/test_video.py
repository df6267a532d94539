"""Video from turtle1's camera (the demo fleet's ``video:``) with real parts: the sim renders, the bridge encodes
H.264 with PyAV, the embedded broker fans it out, the SDK watches and PyAV decodes.

bob (a viewer) watches: the first frame is a keyframe, every frame decodes, each picture's capture time (written in
its pixels by the sim) matches its header; carol (granted turtle2 only) neither starts the camera nor sees a frame;
a flood of watch requests from made-up clients asking for keyframes keeps one stream: frame numbers never restart,
keyframes come at most about once a second, and bob is told he watches from too many clients. When bob leaves,
the frames stop.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

import pytest

from roslink_mqtt.client import RobotClient
from roslink_mqtt.protocol.video import VideoFrame, WatchRequest
from roslink_mqtt.topics import TopicTree, Verb
from roslink_mqtt.video.decoder import VideoDecoder
from roslink_mqtt.video.scene import read_stamp
from roslink_mqtt.video.watchers import MAX_CLIENTS_PER_USER
from tests.support.measure import record_measurement
from tests.support.mqtt_client import TestClient
from tests.support.robot_stack import turtle1_online
from tests.support.waits import paced

pytestmark = pytest.mark.timeout(180)

T = TopicTree()
STREAM = "front_camera"  # the demo fleet's video stream of turtle1
CAMERA = T.state("turtle1", STREAM)


@pytest.fixture(scope="module")
def port(tmp_path_factory) -> Iterator[int]:
    with turtle1_online(tmp_path_factory.mktemp("video")) as port:
        yield port


def _frames(sub, count: int, timeout: float) -> list[VideoFrame]:
    out, deadline = [], time.monotonic() + timeout
    while len(out) < count:
        out.append(sub.get(timeout=max(0.1, deadline - time.monotonic())))
    return out


def test_a_viewer_watches_and_every_picture_says_when_it_was_captured(port: int) -> None:
    with RobotClient("bob", "bob-demo", url=f"mqtt://127.0.0.1:{port}") as bob:
        bob.wait_for_robot("turtle1")
        asked = time.monotonic()
        with bob.video("turtle1", STREAM) as sub:
            frames = _frames(sub, 20, timeout=30)
            first_after = time.monotonic() - asked
        record_measurement("video: watch request → first frame at the viewer (loopback)", first_after, 30.0)
    assert frames[0].key and frames[0].codec == "h264" and frames[0].profile.startswith("avc1.42")
    seqs = [f.seq for f in frames]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs))), seqs  # nothing lost on loopback
    decoder = VideoDecoder()
    readable = 0
    for frame in frames:
        picture = decoder.decode(frame)
        assert picture is not None and (picture.width, picture.height) == (frame.width, frame.height)
        stamp = read_stamp(picture.to_ndarray(format="rgb24"))
        readable += stamp is not None and abs(stamp - frame.stamp) < 0.002
    assert readable >= 15, f"only {readable} of 20 pictures carried their capture time readably"
    ages = sorted(f.encoded - f.stamp for f in frames if f.encoded is not None)
    record_measurement("video: capture → encoded on the robot, median", ages[len(ages) // 2], 1.0)


def test_carol_granted_turtle2_only_neither_starts_the_camera_nor_sees_a_frame(port: int) -> None:
    with TestClient(port, "carol", "carol-demo") as carol, TestClient(port, "alice", "alice-demo") as alice:
        assert carol.connect() == 0 and alice.connect() == 0
        alice.subscribe(CAMERA)
        carol.subscribe(CAMERA)
        for _ in paced(0.5, count=3):  # as a watching client would, renewing
            carol.publish(T.user_topic("turtle1", "carol", Verb.WATCH, STREAM),
                          WatchRequest("carol-web", key=True).to_json(), qos=0)
        # nobody granted watches: alice (who could read them) sees no frame either, so the camera never started
        assert not [m for m in alice.drain(2.0) if m.topic == CAMERA]
        assert not [m for m in carol.drain(0.1) if m.topic == CAMERA]


def test_a_flood_of_watch_requests_keeps_one_stream(port: int) -> None:
    with RobotClient("bob", "bob-demo", url=f"mqtt://127.0.0.1:{port}") as bob, \
            TestClient(port, "bob", "bob-demo", client_id="bob-flood") as flood:
        assert flood.connect() == 0
        flood.subscribe(T.error("turtle1", "bob"))
        bob.wait_for_robot("turtle1")
        with bob.video("turtle1", STREAM) as sub:
            _frames(sub, 5, timeout=30)
            stop = threading.Event()

            def spam() -> None:  # 40 made-up clients, each asking for a keyframe, 1,500 requests in ~1.5 s
                for i in paced(0.001, count=1500, stop=stop.is_set):
                    flood.publish(T.user_topic("turtle1", "bob", Verb.WATCH, STREAM),
                                  WatchRequest(f"bob-fake-{i % 40}", key=True).to_json(), qos=0)

            spammer = threading.Thread(target=spam, daemon=True)
            started = time.monotonic()
            spammer.start()
            during = []
            while time.monotonic() - started < 4.0:
                during.append(sub.get(timeout=10))
            stop.set()
            spammer.join(5)
            for i in range(40):  # the made-up clients leave (or their watches would last their lease)
                flood.publish(T.user_topic("turtle1", "bob", Verb.WATCH, STREAM),
                              WatchRequest(f"bob-fake-{i}", leave=True).to_json(), qos=1)
        errors = [m.json()["error"] for m in flood.drain(1.0) if m.topic == T.error("turtle1", "bob")]
        # the bridge reads a viewer's requests at a bounded rate: the leaves come after the flood's backlog; the next
        # tests need bob's watching clients gone, so wait until the stream has stopped (every watch ended)
        flood.subscribe(CAMERA, qos=0)
        deadline = time.monotonic() + 40
        while [m for m in flood.drain(1.5) if m.topic == CAMERA]:
            assert time.monotonic() < deadline, "the flood's watches never ended"
    seqs = [f.seq for f in during]
    assert seqs == sorted(seqs) and len(during) >= 10, seqs  # one stream: its numbers go on
    keys = sum(f.key for f in during)
    assert keys <= 4.0 + 2, f"{keys} keyframes in 4 s of a keyframe flood"  # at most one a second, and the join's
    assert any(f"already watches from {MAX_CLIENTS_PER_USER} clients" in e for e in errors), errors[:3]


def test_record_watches_a_named_video_stream_and_its_mcap_channel_decodes(port: int, tmp_path) -> None:
    """``roslink-mqtt record --topic front_camera``: the recorder watches the stream (nobody else does), and the
    file's channel is ``foxglove.CompressedVideo`` whose frames decode with PyAV, the first a keyframe."""
    import base64
    import os
    import subprocess
    import sys

    import av
    import orjson
    from mcap.reader import make_reader

    from tests.support.procs import ROOT

    out = tmp_path / "video.mcap"
    done = subprocess.run([sys.executable, "-m", "roslink_mqtt.cli.main", "record", "turtle1", "-o", str(out),
                           "--duration", "6", "--topic", STREAM, "--url", f"mqtt://127.0.0.1:{port}", "-u", "bob"],
                          capture_output=True, text=True, cwd=ROOT, timeout=60,
                          env={**os.environ, "ROSLINK_PASSWORD": "bob-demo"}, stdin=subprocess.DEVNULL)
    assert done.returncode == 0, done.stderr
    with out.open("rb") as f:
        reader = make_reader(f)
        messages = [(schema, channel, message) for schema, channel, message in reader.iter_messages()
                    if channel.topic == CAMERA]
    assert len(messages) >= 10, f"{len(messages)} video frames recorded in 6 s: {done.stderr}"
    assert messages[0][0].name == "foxglove.CompressedVideo"
    frames = [orjson.loads(message.data) for _schema, _channel, message in messages]
    # the recording may begin mid-stream (another watcher's frames): a decoder starts at the first keyframe, which
    # the recorder's own watch asked for
    first_key = next(i for i, f in enumerate(frames) if base64.b64decode(f["data"])[:64].find(b"\x00\x00\x01\x67") >= 0)
    assert first_key < 10, f"no keyframe in the first 10 recorded frames ({first_key})"
    decoder = av.CodecContext.create("h264", "r")
    for frame in frames[first_key:]:
        assert decoder.decode(av.Packet(base64.b64decode(frame["data"]))), "a recorded frame did not decode"


def test_the_cli_saves_a_clip_that_plays_back(port: int, tmp_path) -> None:
    """``roslink-mqtt video turtle1 front_camera --out clip.mp4``: the frames as they came, in a file PyAV plays."""
    import os
    import subprocess
    import sys

    import av

    from tests.support.procs import ROOT

    out = tmp_path / "clip.mp4"
    done = subprocess.run([sys.executable, "-m", "roslink_mqtt.cli.main", "video", "turtle1", STREAM, "--out",
                           str(out), "--duration", "6", "--url", f"mqtt://127.0.0.1:{port}", "-u", "bob"],
                          capture_output=True, text=True, cwd=ROOT, timeout=60,
                          env={**os.environ, "ROSLINK_PASSWORD": "bob-demo"}, stdin=subprocess.DEVNULL)
    assert done.returncode == 0, done.stderr
    assert "fps" in done.stderr and f"→ {out}" in done.stderr, done.stderr
    with av.open(str(out)) as played:
        pictures = sum(1 for _ in played.decode(video=0))
    assert pictures >= 10, f"{pictures} pictures in the clip: {done.stderr}"


def test_when_the_last_viewer_leaves_the_frames_stop(port: int) -> None:
    with TestClient(port, "alice", "alice-demo") as alice:
        assert alice.connect() == 0
        alice.subscribe(CAMERA)
        with RobotClient("bob", "bob-demo", url=f"mqtt://127.0.0.1:{port}") as bob:
            bob.wait_for_robot("turtle1")
            with bob.video("turtle1", STREAM) as sub:
                _frames(sub, 3, timeout=30)
            left = time.monotonic()
        alice.drain(1.0)  # what was on its way
        late = [m for m in alice.drain(2.0) if m.topic == CAMERA]
        assert not late, f"{len(late)} frames more than {time.monotonic() - left:.1f} s after the viewer left"

