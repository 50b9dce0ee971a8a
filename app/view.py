"""``touch2robot view``: the contact feedback view in a browser (viser: a Three.js scene and GUI served from
this process over a websocket, URDF-free: the task scene's MuJoCo geometry posed by MuJoCo's kinematics).

The human side: the 21 keypoints as a skeleton and the nine glove regions coloured by the lake's contacts.
The robot side: the task scene with the LEAP Hand posed by the chosen trajectory, its eight tactile pads
coloured by that trajectory's contacts. A timeline (play/pause, speed, scrub), per-region contact timelines
(human vs robot), the condition switch (Visual Feedback hides every contact cue), the user-study protocol,
and a live mode that follows a glove session while it is written.

The page's contact state is also in the DOM: every region cell of the contact panel carries
``data-side``, ``data-region`` and ``data-contact`` (what the browser tests read), and the panel's
``data-stamp`` is the log time (ns) of the newest message shown (what the live latency is measured from).
"""

from __future__ import annotations

import errno
import socket
import threading
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from schemas.tables import HUMAN_REGIONS, ROBOT_REGIONS
from touch2robot.geometry import quat_to_mat
from touch2robot.settings import DataLayout
from touch2robot.stats import CONDITIONS, RATING_MAX, RATING_MIN
from touch2robot.view import study
from touch2robot.view.demonstration import Demonstration, RobotTrajectory, ViewError, load_trajectory
from touch2robot.view.follow import FollowError, LiveSession
from touch2robot.view.pose import (
    CONTACT_RGB,
    IDLE_REGION_RGB,
    ScenePoser,
    glove_region_points,
    human_groups,
    posed_bones,
    posed_vertices,
    scene_groups,
)

VISUAL_FEEDBACK, TOUCH2ROBOT = CONDITIONS
HUMAN_OFFSET = np.array([0.0, 0.32, 0.0])  # the human side, beside the robot scene (m)
FRAME_RATE_HZ = 30.0
SPEEDS = ("0.25", "0.5", "1", "2")


class PortInUse(OSError):
    """The port the view should serve on is taken."""


def check_port(host: str, port: int) -> None:
    """Raise ``PortInUse`` if ``host:port`` cannot be bound (viser would silently move to another port)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # a closed view's TIME_WAIT is not "in use"
        try:
            s.bind((host, port))
        except OSError as e:
            if e.errno in (errno.EADDRINUSE, errno.EACCES):
                raise PortInUse(f"port {port} on {host} is in use: pass another with --port") from None
            raise


def _rgb_css(rgb: tuple[int, int, int]) -> str:
    return f"rgb({rgb[0]}, {rgb[1]}, {rgb[2]})"


def contact_panel_html(
    human: np.ndarray, robot: np.ndarray | None, robot_label: str, stamp_ns: int, t: float, note: str = ""
) -> str:
    """The contact panel: one cell per human region (9) and robot region (8), ``data-contact`` 1 or 0."""

    def cells(side: str, regions: tuple[str, ...], contact: np.ndarray | None) -> str:
        out = []
        for k, region in enumerate(regions):
            on = bool(contact is not None and contact[k])
            color = _rgb_css(CONTACT_RGB if on else IDLE_REGION_RGB)
            out.append(
                f'<span data-side="{side}" data-region="{region}" data-contact="{int(on)}" '
                f'style="display:inline-block;width:30px;margin:1px;padding:4px 0;text-align:center;'
                f'color:white;font:12px sans-serif;background:{color}">{region}</span>'
            )
        return "".join(out)

    return (
        f'<div id="contact-panel" data-stamp="{stamp_ns}" data-t="{t:.4f}" style="font:12px sans-serif">'
        f"<div>human (glove)</div><div>{cells('human', HUMAN_REGIONS, human)}</div>"
        f"<div>robot ({robot_label})</div><div>{cells('robot', ROBOT_REGIONS, robot)}</div>"
        f'<div style="color:#666">{note}</div></div>'
    )


def _segments(t: np.ndarray, on: np.ndarray) -> list[tuple[float, float]]:
    """(start, end) of each run of True in ``on`` sampled at ``t``."""
    if not len(t):
        return []
    edges = np.flatnonzero(np.diff(np.concatenate([[0], on.astype(np.int8), [0]])))
    ends = np.append(t, t[-1])
    return [(float(t[a]), float(ends[b])) for a, b in zip(edges[::2], edges[1::2], strict=True)]


TIMELINE_WIDTH = 260


def _timeline_x(demo: Demonstration, s: float) -> float:
    return 30 + (TIMELINE_WIDTH - 34) * (s - float(demo.t[0])) / max(demo.duration, 1e-6)


def timeline_rows(demo: Demonstration, trajectory: RobotTrajectory | None) -> str:
    """The per-region contact timelines' SVG rows: for each robot region the human's (top) and the robot's
    (bottom) contact intervals over the demonstration (they change with the trajectory, not the time)."""
    width = TIMELINE_WIDTH
    x = lambda s: _timeline_x(demo, s)  # noqa: E731
    rows = []
    for k, region in enumerate(ROBOT_REGIONS):
        y = 4 + 18 * k
        rows.append(f'<text x="0" y="{y + 11}" font-size="10">{region}</text>')
        rows.append(f'<rect x="30" y="{y}" width="{width - 34}" height="14" fill="#eee"/>')
        h = HUMAN_REGIONS.index(region)
        for a, b in _segments(demo.contact_t, demo.contacts[:, h]):
            rows.append(f'<rect x="{x(a):.1f}" y="{y}" width="{max(x(b) - x(a), 1):.1f}" height="6" fill="#e8a33d"/>')
        if trajectory is not None:
            for a, b in _segments(trajectory.contact_t, trajectory.contacts[:, k]):
                rows.append(
                    f'<rect x="{x(a):.1f}" y="{y + 8}" width="{max(x(b) - x(a), 1):.1f}" height="6" '
                    f'fill="{_rgb_css(CONTACT_RGB)}"/>'
                )
    return "".join(rows)


def timeline_svg(demo: Demonstration, rows: str, t: float) -> str:
    """The timelines (``timeline_rows``) with a cursor at ``t``."""
    height = 8 + 18 * len(ROBOT_REGIONS)
    x = _timeline_x(demo, t)
    cursor = f'<line x1="{x:.1f}" x2="{x:.1f}" y1="0" y2="{height}" stroke="black"/>'
    legend = '<div style="font:10px sans-serif">top: human (glove) · bottom: robot</div>'
    return f'<svg id="timelines" width="{TIMELINE_WIDTH}" height="{height}">{rows}{cursor}</svg>{legend}'


@dataclass
class _Playback:
    t: float = 0.0
    playing: bool = False
    speed: float = 1.0


class FeedbackView:
    """The view of one demonstration (and optionally a live glove session) on ``host:port``."""

    def __init__(
        self,
        layout: DataLayout,
        demo: Demonstration,
        host: str = "127.0.0.1",
        port: int = 8080,
        trajectory: str | None = None,
        live: LiveSession | None = None,
        time_budget_s: float = 60.0,
        ratings: Path | None = None,
    ) -> None:
        import viser

        self.layout, self.demo, self.live = layout, demo, live
        self.ratings_path = ratings or layout.user_study / study.STUDY_RATINGS_FILE
        self.time_budget_s = time_budget_s
        self.poser = ScenePoser(demo.task)
        self.play = _Playback(t=float(demo.t[0]) if len(demo.t) else 0.0)
        self.condition = TOUCH2ROBOT
        self.trajectory: RobotTrajectory | None = None
        self.participant: study.Participant | None = None
        self._trial_started: float | None = None
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._timeline_rows = timeline_rows(demo, None)
        self._glove_at: np.ndarray | None = None  # the glove markers' last positions (live: keypoints come apart)
        self.latency_ms: deque[float] = deque(maxlen=2000)
        self._last_stamp = 0
        check_port(host, port)
        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        self.server.scene.set_up_direction("+z")
        # no shadow maps: they double each frame's rendering, and a software-rendered page (headless, no GPU)
        # then fell seconds behind a live session
        self.server.scene.configure_default_lights(cast_shadow=False)
        # and no image-based lighting: the HDRI environment map cost a software-rendered page 6x its frame rate
        # (headless Chromium at 1280x800: 2.2 -> 13.6 frames/s); a hemisphere light keeps the shading readable
        self.server.scene.configure_environment_map(None)
        self.server.scene.add_light_hemisphere(
            "/light/sky", sky_color=(255, 255, 255), ground_color=(90, 90, 100), intensity=1.5
        )
        # from in front of the fingers (+x), so the robot (y = 0) and the human (y = HUMAN_OFFSET) sit side by side
        self.server.initial_camera.position = (0.48, 0.16, 0.34)
        self.server.initial_camera.look_at = (0.0, 0.16, 0.06)
        self._build_scene()
        self._build_gui()
        choices = {c.key: c for c in demo.trajectories}
        if trajectory is not None and trajectory not in choices:
            raise ViewError(
                f"trajectory {trajectory!r} is not one of recording {demo.recording_id}'s: "
                + (", ".join(choices) or "it has none yet (run teachers, student or replay)")
            )
        first = trajectory or next(iter(choices), None)
        if first is not None:
            self._select(choices[first].label)
        self.show(self.play.t)
        if live is not None:
            xpos, xquat = self.poser.pose()
            idle = np.zeros(len(HUMAN_REGIONS), bool)
            note = f"live: waiting for {live.tail.path.name}"
            self._draw(xpos, xquat, None, idle, None, "live: glove contacts on its regions", 0, 0.0, note)

    # ------------------------------------------------------------------ scene
    def _build_scene(self) -> None:
        # A few merged meshes whose vertices are posed here, one message each a frame: a node per body and bone
        # (80 pose messages a frame) kept a software-rendered page (headless Chromium) seconds behind a live
        # session, and so did per-node colour changes (measured with tests/test_view.py's live page).
        scene = self.server.scene
        self.groups = scene_groups(self.poser)
        self.bone_group, *self.glove_groups = human_groups()
        self.meshes = {}
        for group in (*self.groups, self.bone_group, *self.glove_groups):
            n = sum(len(p) for p in group.parts)
            self.meshes[group.key] = scene.add_mesh_simple(
                f"/scene/{group.key}",
                np.zeros((n, 3), np.float32),
                group.faces,
                color=group.color,
                cast_shadow=False,
                receive_shadow=False,
            )
        scene.add_label("/labels/robot", "robot", position=(0.0, -0.12, 0.3))
        scene.add_label("/labels/human", "human (glove)", position=tuple(HUMAN_OFFSET + [0.0, 0.0, 0.3]))
        self._sent: dict[str, np.ndarray] = {}

    # ------------------------------------------------------------------ GUI
    def _build_gui(self) -> None:
        gui = self.server.gui
        demo = self.demo
        gui.add_markdown(f"**{demo.file_name}** · {demo.task} · {demo.subject}")
        self.condition_switch = gui.add_dropdown("Condition", CONDITIONS, initial_value=self.condition)
        self.condition_switch.on_update(lambda _: self._set_condition(self.condition_switch.value))
        labels = [c.label for c in demo.trajectories] or ["(no robot trajectory in the lake)"]
        self.trajectory_menu = gui.add_dropdown("Trajectory", labels, initial_value=labels[0])
        self.trajectory_menu.on_update(lambda _: self._select(self.trajectory_menu.value))
        start, end = (float(demo.t[0]), float(demo.t[-1])) if len(demo.t) else (0.0, 1.0)
        self.time_slider = gui.add_slider(
            "Time (s)", min=start, max=max(end, start + 0.01), step=0.01, initial_value=start
        )
        self.time_slider.on_update(lambda _: self.show(self.time_slider.value))
        self.play_button = gui.add_button("Play")
        self.play_button.on_click(lambda _: self._toggle_play())
        self.speed = gui.add_dropdown("Speed", SPEEDS, initial_value="1")
        self.speed.on_update(lambda _: setattr(self.play, "speed", float(self.speed.value)))
        self.panel = gui.add_html("")
        self.timelines = gui.add_html("")
        self.status = gui.add_markdown("")
        with gui.add_folder("User study"):
            self.participant_id = gui.add_text("Participant", initial_value="")
            self.start_button = gui.add_button("Start study")
            self.start_button.on_click(lambda _: self._start_study())
            self.done_button = gui.add_button("End condition", visible=False)
            self.done_button.on_click(lambda _: self._end_trial())
            self.study_status = gui.add_markdown("")
            self.questions = {
                q: gui.add_slider(
                    f"{q}: {text}", min=RATING_MIN, max=RATING_MAX, step=1, initial_value=4, visible=False
                )
                for q, text in study.QUESTIONNAIRE.items()
            }
            self.submit_button = gui.add_button("Submit answers", visible=False)
            self.submit_button.on_click(lambda _: self._submit())

    # ------------------------------------------------------------------ state
    def _select(self, label: str) -> None:
        choice = next((c for c in self.demo.trajectories if c.label == label), None)
        if choice is None:
            return
        try:
            trajectory = load_trajectory(self.layout, choice)
        except ViewError as e:
            self._note(str(e))
            return
        with self._lock:
            self.trajectory = trajectory
            self._timeline_rows = timeline_rows(self.demo, trajectory)
            if self.trajectory_menu.value != label:
                self.trajectory_menu.value = label
        self.show(self.play.t)

    def _set_condition(self, condition: str) -> None:
        with self._lock:
            self.condition = condition
            if self.condition_switch.value != condition:
                self.condition_switch.value = condition
        self.show(self.play.t)

    def _toggle_play(self) -> None:
        self.play.playing = not self.play.playing
        self.play_button.label = "Pause" if self.play.playing else "Play"

    def _note(self, text: str) -> None:
        self.status.content = text

    @property
    def contacts_shown(self) -> bool:
        return self.condition == TOUCH2ROBOT

    def show(self, t: float) -> None:
        """Pose both sides at reference time ``t`` and update the contact cues."""
        if self.live is not None:
            return  # the live loop owns the display
        with self._lock:
            demo, trajectory = self.demo, self.trajectory
            self.play.t = float(t)
            human = demo.contacts_at(t)
            robot = trajectory.contacts_at(t) if trajectory is not None else None
            keypoints = demo.keypoints_at(t)
            if trajectory is not None:
                joints, wrist, obj, drawer = trajectory.at(t)
                xpos, xquat = self.poser.pose(joints, wrist, obj, drawer)
            else:
                xpos, xquat = self.poser.pose()
            label = trajectory.choice.label if trajectory is not None else "none"
            note = "T5: no robot counterpart, not stored in the lake"
            self._draw(xpos, xquat, keypoints, human, robot, label, 0, t, note)
            self.timelines.content = timeline_svg(demo, self._timeline_rows, t)
            self.timelines.visible = self.contacts_shown
        if abs(self.time_slider.value - t) > 1e-6:
            self.time_slider.value = round(float(t), 2)

    def _draw(
        self,
        xpos: np.ndarray,
        xquat: np.ndarray,
        keypoints: np.ndarray | None,
        human: np.ndarray,
        robot: np.ndarray | None,
        label: str,
        stamp_ns: int,
        t: float,
        note: str,
    ) -> None:
        shown = self.contacts_shown
        with self.server.atomic():
            rotation = quat_to_mat(xquat)
            robot_on = np.zeros(len(ROBOT_REGIONS), bool) if robot is None or not shown else np.asarray(robot, bool)
            for group in self.groups:
                visible = None
                if group.key == "pads":
                    visible = ~robot_on
                elif group.key == "pads_contact":
                    visible = robot_on
                self._send(group.key, posed_vertices(group, xpos, rotation, visible))
            if keypoints is not None:
                points = keypoints + HUMAN_OFFSET
                self._send("bones", posed_bones(self.bone_group, points))
                at = glove_region_points(points)
                self._glove_at = np.stack([at[r] for r in HUMAN_REGIONS])
            if self._glove_at is not None:
                human_on = np.asarray(human, bool) & shown
                eye = np.tile(np.eye(3), (len(HUMAN_REGIONS), 1, 1))
                idle, touching = self.glove_groups
                self._send("glove", posed_vertices(idle, self._glove_at, eye, ~human_on))
                self._send("glove_contact", posed_vertices(touching, self._glove_at, eye, human_on))
            self.panel.content = contact_panel_html(human, robot, label, stamp_ns, t, note)
            self.panel.visible = shown

    def _send(self, key: str, vertices: np.ndarray) -> None:
        """Send a merged mesh's vertices when they changed (every update is a message the page applies)."""
        last = self._sent.get(key)
        if last is not None and np.array_equal(last, vertices):
            return
        self._sent[key] = vertices
        self.meshes[key].vertices = vertices

    # ------------------------------------------------------------------ study
    def _start_study(self) -> None:
        try:
            self.participant = study.start(self.ratings_path, self.participant_id.value.strip(), self.demo.recording_id)
        except study.StudyError as e:
            self.study_status.content = f"**{e}**"
            return
        self.start_button.disabled = self.participant_id.disabled = True
        self._begin_trial()

    def _begin_trial(self) -> None:
        session = self.participant
        assert session is not None and session.current is not None
        self._set_condition(session.current)
        self.condition_switch.disabled = True  # the protocol, not the participant, picks the condition
        self.play.playing = False
        self.show(float(self.demo.t[0]))  # the same initial state for both conditions
        self._toggle_play()
        self._trial_started = time.monotonic()
        self.done_button.visible = True
        position = session.order.index(session.current) + 1
        self.study_status.content = (
            f"Participant {session.participant}: condition {position} of 2, **{session.current}**, "
            f"{self.time_budget_s:.0f} s"
        )

    def _end_trial(self) -> None:
        if self.participant is None or self._trial_started is None:
            return
        self._trial_started = None
        self.play.playing = False
        self.play_button.label = "Play"
        self.done_button.visible = False
        for slider in self.questions.values():
            slider.value = 4
            slider.visible = True
        self.submit_button.visible = True
        self.study_status.content = f"Questionnaire for **{self.participant.current}** (1 = disagree, 7 = agree)"

    def _submit(self) -> None:
        session = self.participant
        if session is None:
            return
        try:
            session.answer({q: round(s.value) for q, s in self.questions.items()})
        except study.StudyError as e:
            self.study_status.content = f"**{e}**"
            return
        for slider in self.questions.values():
            slider.visible = False
        self.submit_button.visible = False
        if session.current is not None:
            self._begin_trial()
            return
        try:
            n = study.save(self.ratings_path, session)
            self.study_status.content = (
                f"Saved {n} ratings of {session.participant} to {self.ratings_path.name}. Thank you."
            )
        except (study.StudyError, OSError) as e:
            self.study_status.content = f"**not saved: {e}**"
        self.participant = None
        self.start_button.disabled = self.participant_id.disabled = False
        self.condition_switch.disabled = False
        self.participant_id.value = ""

    # ------------------------------------------------------------------ loops
    def _tick_playback(self, dt: float) -> None:
        if self._trial_started is not None and time.monotonic() - self._trial_started >= self.time_budget_s:
            self._end_trial()
        if not self.play.playing:
            return
        t = self.play.t + dt * self.play.speed
        end = float(self.demo.t[-1]) if len(self.demo.t) else 0.0
        if t >= end:  # loop: a trial lasts its time budget, not the demonstration's length
            t = float(self.demo.t[0])
        self.show(t)

    def _tick_live(self) -> None:
        live = self.live
        assert live is not None
        try:
            frame = live.update()
        except FollowError as e:
            self._note(f"**{e}**; showing what was read before")
            self.live = None  # keep serving the last frame; the file cannot be read further
            return
        if frame is None:
            return
        if frame.joints is not None and frame.wrist is not None:
            xpos, xquat = self.poser.pose(frame.joints, frame.wrist)
        else:
            xpos, xquat = self.poser.pose()
        robot = frame.contacts[[HUMAN_REGIONS.index(r) for r in ROBOT_REGIONS]]
        note = f"live: {live.tail.path.name} at {frame.t:.2f} s" + (" (finished)" if live.tail.finished else "")
        with self._lock:
            self._draw(
                xpos,
                xquat,
                frame.keypoints,
                frame.contacts,
                robot,
                "live: glove contacts on its regions",
                frame.stamp_ns,
                frame.t,
                note,
            )
        if frame.stamp_ns != self._last_stamp:
            self._last_stamp = frame.stamp_ns
            self.latency_ms.append((time.time_ns() - frame.stamp_ns) / 1e6)  # message stamp -> sent to the page

    def serve_forever(self, rate_hz: float = FRAME_RATE_HZ) -> None:
        """Run the playback (or live) loop until :meth:`stop` or Ctrl-C."""
        period = 1.0 / rate_hz
        last = time.monotonic()
        try:
            while not self._stop.is_set():
                now = time.monotonic()
                if self.live is not None:
                    self._tick_live()
                else:
                    self._tick_playback(now - last)
                last = now
                self._stop.wait(max(0.0, period - (time.monotonic() - now)))
        finally:
            self.server.stop()

    def stop(self) -> None:
        self._stop.set()


__all__ = ["FeedbackView", "PortInUse", "check_port", "contact_panel_html", "timeline_svg"]
