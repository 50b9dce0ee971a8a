"""The contact feedback view (`touch2robot view`): a real viser server, driven by Debian's Chromium under
Playwright, over a lake holding a glove session, a teacher rollout with contact rows and its twin replay;
the growing-file reader behind live mode; the study protocol into `evaluate`'s user_study table; the Rerun
export; and the command's answers to bad input."""

from __future__ import annotations

import shutil
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
from conftest import scripted_rollout_rows
from playwright.sync_api import Page

from app.view import FeedbackView
from schemas.tables import HUMAN_REGIONS, ROBOT_REGIONS, SCHEMAS
from schemas.vocabulary import Source
from touch2robot import catalog, datasets
from touch2robot import lake as lake_io
from touch2robot.contacts import ContactsConfig, long_rows
from touch2robot.settings import DataLayout
from touch2robot.view import study
from touch2robot.view.demonstration import ViewError, load_demonstration, load_trajectory
from touch2robot.view.follow import FollowError, McapTail

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
ROLLOUT = "teacher-touch2robot-pick-000"
TOUCHING = ("T2", "P1")  # the rollout's contact rows: exactly these while STEPS_TOUCHING
STEPS_TOUCHING = range(12, 26)
STEPS = 40


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def view_data(demo_lake: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """demo_lake's glove sessions plus, for the pick session: a scripted teacher rollout (MuJoCo physics)
    whose `contacts` rows say T2 and P1 touch during STEPS_TOUCHING, and that rollout executed on the
    hardware twin, ingested, with its real contacts; the catalog refreshed."""
    from touch2robot.contacts.extract import replay_contacts
    from touch2robot.ingest import ingest_file, recording_rows
    from touch2robot.sim.config import SimConfig
    from touch2robot.twin.config import TwinConfig
    from touch2robot.twin.replay import replay_rollout

    root = tmp_path_factory.mktemp("view") / "data"
    shutil.copytree(demo_lake, root)
    layout = DataLayout(root)
    glove = next(r for r in recording_rows(layout.lake).to_pylist() if r["task"] == "pick")
    rows = scripted_rollout_rows("pick", "touch2robot", 1, STEPS)
    rows = rows.set_column(rows.schema.get_field_index("rollout_id"), "rollout_id", pa.array([ROLLOUT] * len(rows)))
    rows = rows.set_column(
        rows.schema.get_field_index("reference_id"), "reference_id", pa.array([glove["recording_id"]] * len(rows))
    )
    rows = rows.select(SCHEMAS["rollouts"].names).cast(SCHEMAS["rollouts"])
    datasets.ROLLOUTS.write(layout.lake, datasets.rollouts_key("teacher", "pick", 0), rows, method="touch2robot")
    steps = rows["step"].to_numpy()
    contact = np.zeros((len(steps), len(ROBOT_REGIONS)), bool)
    for region in TOUCHING:
        contact[np.isin(steps, STEPS_TOUCHING), ROBOT_REGIONS.index(region)] = True
    sim = long_rows(
        source=Source.SIM,
        method="touch2robot",
        task="pick",
        subject=glove["subject"],
        sequence_id=ROLLOUT,
        reference_id=glove["recording_id"],
        t=rows["t"].to_numpy(),
        t_ref=rows["t_ref"].to_numpy(),
        regions=ROBOT_REGIONS,
        contact=contact,
        value=contact.astype(np.float32),
    )
    lake_io.write_rows(
        layout.lake, "contacts", "teacher-touch2robot-pick-seed0", sim, {"source": "sim", "task": "pick"}
    )
    stem = Path(glove["file_name"]).name.removesuffix("_glove.mcap") + "_touch2robot"
    replay, calibration = layout.recordings / f"{stem}_replay.mcap", layout.recordings / f"{stem}_calib.mcap"
    metadata = {
        "task": "pick",
        "subject": glove["subject"],
        "method": "touch2robot",
        "reference_recording": glove["file_name"],
        "calibration_recording": calibration.name,
        "trajectory": ROLLOUT,
        "rig": "simulated",
    }
    replay_rollout(rows, SimConfig(threads=1), TwinConfig(), (0,), replay, calibration, metadata)
    ingest_file(calibration, layout.lake)
    ingest_file(replay, layout.lake)
    recordings = {r["file_name"]: r for r in recording_rows(layout.lake).to_pylist()}
    replayed = recordings[replay.name]
    real, _ = replay_contacts(
        layout.lake, replayed, recordings[calibration.name]["recording_id"], glove, ContactsConfig()
    )
    lake_io.write_rows(layout.lake, "contacts", replayed["recording_id"], real, {"source": "real", "task": "pick"})
    catalog.refresh(layout)
    return root


@pytest.fixture(scope="module")
def pick_demo(view_data: Path):
    layout = DataLayout(view_data)
    sql = "SELECT recording_id FROM recordings WHERE task = 'pick' AND kind = 'glove_session'"
    return layout, load_demonstration(layout, catalog.query(layout, sql).to_pylist()[0]["recording_id"])


def test_a_demonstration_lists_its_trajectories_and_a_twin_replay_is_posed_on_the_reference_clock(pick_demo) -> None:
    layout, demo = pick_demo
    kinds = {c.kind: c for c in demo.trajectories}
    assert set(kinds) == {"rollout", "replay"} and kinds["rollout"].key == ROLLOUT
    rollout = load_trajectory(layout, kinds["rollout"])
    t_touch = float(rollout.t_ref[STEPS_TOUCHING.start + 2])
    assert {ROBOT_REGIONS[k] for k in np.flatnonzero(rollout.contacts_at(t_touch))} == set(TOUCHING)
    assert not rollout.contacts_at(float(rollout.t_ref[2])).any()
    replay = load_trajectory(layout, kinds["replay"])
    assert replay.contact_source == "real" and len(replay.t_ref) > len(rollout.t_ref)
    # the twin's measured joints follow the rollout's commands on the reference clock (perturbed: close, not equal)
    commanded = np.stack([rollout.at(float(t))[0] for t in replay.t_ref])
    assert np.abs(replay.joints - commanded).mean() < 0.15
    assert replay.t_ref[0] >= -0.05 and replay.t_ref[-1] <= rollout.t_ref[-1] + 0.2


def test_an_unknown_recording_is_refused_with_the_sessions_that_exist(pick_demo) -> None:
    layout, demo = pick_demo
    with pytest.raises(
        ViewError, match=r"'nope' is not in the lake's recordings; glove sessions: .*pick_s01_d01_glove"
    ):
        load_demonstration(layout, "nope")
    replay = next(c for c in demo.trajectories if c.kind == "replay")
    with pytest.raises(ViewError, match="is a robot_replay recording"):
        load_demonstration(layout, replay.key)


# ---------------------------------------------------------------------------------------------- browser


@contextmanager
def _served(layout: DataLayout, demo, **options) -> Iterator[tuple[FeedbackView, str]]:
    port = _free_port()
    view = FeedbackView(layout, demo, port=port, **options)
    thread = threading.Thread(target=view.serve_forever, daemon=True)
    thread.start()
    try:
        yield view, f"http://127.0.0.1:{port}"
    finally:
        view.stop()
        thread.join(10)


@contextmanager
def _page(url: str) -> Iterator[Page]:
    if not Path(CHROMIUM).is_file():
        pytest.fail(
            f"the view's browser tests need Debian's chromium: {CHROMIUM} is missing (apt-get install chromium)"
        )
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(
            executable_path=CHROMIUM,
            args=[
                "--no-sandbox",
                "--use-angle=swiftshader",
                "--enable-unsafe-swiftshader",
                "--disable-background-networking",
            ],
        )
        try:
            page = browser.new_page(viewport={"width": 1400, "height": 900})
            page.goto(url)
            page.wait_for_selector("#contact-panel", timeout=60_000)
            page.wait_for_selector("canvas", timeout=60_000)
            yield page
        finally:
            browser.close()


def _field(page, label: str):
    """The text box of the GUI control labelled ``label`` (viser: a label and its input in one row)."""
    box = page.locator(
        f"xpath=//label[starts-with(normalize-space(.), '{label}')]/ancestor::div[2]//input[not(@type) or @type='text']"
    )
    assert box.count() == 1, label
    return box


def _choose(page, label: str, option: str) -> None:
    page.get_by_label(label).click()
    page.get_by_role("option", name=option).click()


def _canvas_pixels(page) -> np.ndarray:
    import io

    from PIL import Image

    png = page.locator("canvas").first.screenshot()
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)


def _contact_pixels(pixels: np.ndarray, robot_side: bool = False) -> int:
    """Pixels of the view's contact magenta (shaded: red and blue high, green low); ``robot_side``: only the
    left half of the canvas, where the initial camera shows the robot (the human is right of it, the GUI
    panel at the right edge)."""
    if robot_side:
        pixels = pixels[:, : int(0.52 * pixels.shape[1])]
    r, g, b = pixels[..., 0], pixels[..., 1], pixels[..., 2]
    return int(((r > 170) & (b > 100) & (g < 90) & (r > b)).sum())


def _regions_on(page, side: str) -> set[str]:
    cells = page.locator(f"#contact-panel [data-side='{side}'][data-contact='1']")
    return {cells.nth(k).get_attribute("data-region") for k in range(cells.count())}


def _scrub(page, t: float) -> None:
    box = _field(page, "Time (s)")
    box.fill(f"{t:.2f}")
    box.press("Enter")
    page.wait_for_selector(f"#contact-panel[data-t^='{t:.2f}']", timeout=20_000)


def test_the_page_loads_with_a_drawn_scene_and_scrubbing_shows_exactly_the_lakes_contacts(pick_demo, tmp_path) -> None:
    layout, demo = pick_demo
    rollout = load_trajectory(layout, next(c for c in demo.trajectories if c.key == ROLLOUT))
    t_touch = round(float(rollout.t_ref[STEPS_TOUCHING.start + 3]), 2)
    t_free = round(float(rollout.t_ref[3]), 2)
    lake_human = {  # what the lake says about the human at t_touch
        r["region"]
        for r in catalog.query(
            layout,
            f"SELECT region, contact FROM contacts WHERE source = 'human' AND sequence_id = '{demo.recording_id}'"
            f" AND t_ref = (SELECT max(t_ref) FROM contacts WHERE source = 'human'"
            f" AND sequence_id = '{demo.recording_id}' AND t_ref <= {t_touch})",
        ).to_pylist()
        if r["contact"]
    }
    with _served(layout, demo, trajectory=ROLLOUT) as (_, url), _page(url) as page:
        pixels = _canvas_pixels(page)
        assert pixels.shape[0] > 400 and len(np.unique(pixels.reshape(-1, 3), axis=0)) > 200  # not blank
        _scrub(page, t_free)
        assert _regions_on(page, "robot") == set()
        assert _contact_pixels(_canvas_pixels(page), robot_side=True) < 30
        _scrub(page, t_touch)
        assert _regions_on(page, "robot") == set(TOUCHING)
        assert _regions_on(page, "human") == lake_human
        # the pixel colour of the highlighted cells, and the pads in the 3D scene
        page.screenshot(path=str(tmp_path / "touch2robot.png"))
        for region in ROBOT_REGIONS:
            cell = page.locator(f"#contact-panel [data-side='robot'][data-region='{region}']")
            colour = cell.evaluate("e => getComputedStyle(e).backgroundColor")
            assert (colour == "rgb(255, 26, 168)") == (region in TOUCHING), (region, colour)
        assert _contact_pixels(_canvas_pixels(page), robot_side=True) > 30


def test_the_condition_switch_hides_and_shows_every_contact_cue(pick_demo) -> None:
    layout, demo = pick_demo
    rollout = load_trajectory(layout, next(c for c in demo.trajectories if c.key == ROLLOUT))
    t_touch = round(float(rollout.t_ref[STEPS_TOUCHING.start + 3]), 2)
    with _served(layout, demo, trajectory=ROLLOUT) as (view, url), _page(url) as page:
        _scrub(page, t_touch)
        assert (
            _regions_on(page, "robot") == set(TOUCHING) and _contact_pixels(_canvas_pixels(page), robot_side=True) > 30
        )
        _choose(page, "Condition", "Visual Feedback")
        page.wait_for_selector("#contact-panel", state="detached", timeout=20_000)
        page.wait_for_timeout(500)
        assert page.locator("[data-contact]").count() == 0 and page.locator("#timelines").count() == 0
        assert _contact_pixels(_canvas_pixels(page)) < 30  # the pads and glove markers lose their contact colour
        _choose(page, "Condition", "Touch2Robot")
        page.wait_for_selector("#contact-panel", timeout=20_000)
        assert _regions_on(page, "robot") == set(TOUCHING)
        assert view.condition == "Touch2Robot"


def test_a_questionnaire_submitted_through_the_page_arrives_in_the_user_study_table_after_evaluate(
    pick_demo, tmp_path: Path
) -> None:
    layout, demo = pick_demo
    ratings = layout.user_study / study.STUDY_RATINGS_FILE
    answers = {"Visual Feedback": (3, 2, 4, 3), "Touch2Robot": (6, 7, 5, 6)}
    with _served(layout, demo, trajectory=ROLLOUT, time_budget_s=600) as (view, url), _page(url) as page:
        participant = _field(page, "Participant")
        participant.fill("p07")
        participant.press("Tab")
        page.get_by_role("button", name="Start study").click()
        for position in (1, 2):
            page.get_by_role("button", name="End condition").click()
            page.get_by_role("button", name="Submit answers").wait_for(timeout=20_000)
            assert view.participant is not None
            condition = view.participant.current
            assert condition is not None
            assert view.condition == condition and condition == study.condition_order(0)[position - 1]
            for q, rating in zip(study.QUESTIONNAIRE, answers[condition], strict=True):
                box = _field(page, f"{q}:")
                box.fill(str(rating))
                box.press("Tab")
                deadline = time.monotonic() + 20
                while view.questions[q].value != rating and time.monotonic() < deadline:
                    page.wait_for_timeout(50)
            page.get_by_role("button", name="Submit answers").click()
            if position == 2:
                page.get_by_text("Saved 8 ratings of p07").wait_for(timeout=20_000)
    saved = study.read_ratings(ratings)
    assert len(saved) == 8 and set(saved["participant"]) == {"p07"}
    for condition, values in answers.items():
        got = saved[saved["condition"] == condition].sort_values("question")["rating"].tolist()
        assert got == list(values)
    # evaluate: the real ratings file's statistics, labelled real, and the SYNTHETIC example left out
    from touch2robot.synth.ratings import synthetic_ratings

    synthetic_ratings(4).to_csv(layout.synthetic_ratings, index=False)
    _run_evaluate(layout)
    table = catalog.query(
        layout, "SELECT ratings_file, question, synthetic, median_touch2robot FROM user_study"
    ).to_pylist()
    assert {r["ratings_file"] for r in table} == {study.STUDY_RATINGS_FILE}
    assert all(not r["synthetic"] for r in table) and len(table) == 4
    assert {r["question"]: r["median_touch2robot"] for r in table} == dict(
        zip(study.QUESTIONNAIRE, (6.0, 7.0, 5.0, 6.0), strict=True)
    )


def _run_evaluate(layout: DataLayout) -> None:
    """The `evaluate` command on the data folder (its own Prefect API and MLflow store)."""
    done = subprocess.run(
        [sys.executable, "-m", "app.cli", "evaluate", "--profile", "smoke", "--data", str(layout.root)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]


# ---------------------------------------------------------------------------------------------- live


def test_a_recording_cut_mid_chunk_is_read_up_to_its_last_complete_record_and_resumes_when_it_grows(
    pick_demo, tmp_path: Path
) -> None:
    from mcap.reader import make_reader

    layout, demo = pick_demo
    source = (layout.recordings / demo.file_name).read_bytes()
    with open(layout.recordings / demo.file_name, "rb") as f:
        expected = sum(1 for _ in make_reader(f).iter_messages())
    growing = tmp_path / "growing.mcap"
    tail = McapTail(growing)
    growing.write_bytes(b"")
    assert tail.poll() == {}
    seen = 0
    for cut in (5, 64, len(source) // 3, len(source) // 3 + 7, 2 * len(source) // 3, len(source)):
        growing.write_bytes(source[:cut])  # the recorder's file, cut anywhere: in the magic, a chunk, the summary
        seen += sum(len(v) for v in tail.poll().values())
    assert seen == expected and tail.finished
    corrupt = tmp_path / "corrupt.mcap"
    corrupt.write_bytes(source[:4000] + b"\xff" * 200 + source[4200:])
    with pytest.raises(FollowError, match=r"corrupt.mcap: corrupt record"):
        bad = McapTail(corrupt)
        for _ in range(3):
            bad.poll()
    not_mcap = tmp_path / "notes.mcap"
    not_mcap.write_text("hello, not a recording")
    with pytest.raises(FollowError, match=r"notes\.mcap: not an MCAP file"):
        McapTail(not_mcap).poll()


def test_live_mode_follows_a_recording_replayed_in_real_time_and_the_page_shows_its_newest_contacts(
    pick_demo, tmp_path
) -> None:
    from touch2robot.contacts import glove_contacts
    from touch2robot.view.follow import LiveSession, live_retargeter, replay_in_real_time

    layout, demo = pick_demo
    growing = tmp_path / "live.mcap"  # not there yet: the view waits for the recorder
    stop = threading.Event()
    writer = threading.Thread(
        target=replay_in_real_time, args=(layout.recordings / demo.file_name, growing, stop), daemon=True
    )
    session = LiveSession(growing, retarget=live_retargeter())
    try:
        with _served(layout, demo, live=session) as (view, url), _page(url) as page:
            assert page.locator("#contact-panel").get_attribute("data-stamp") == "0"
            page.get_by_text("waiting for live.mcap").wait_for(timeout=20_000)
            page.evaluate(
                """() => { window.shown = []; new MutationObserver(() => {
                    const p = document.querySelector('#contact-panel');
                    if (p) window.shown.push([p.dataset.stamp, performance.timeOrigin + performance.now()]);
                }).observe(document.body, {subtree: true, childList: true, attributes: true}); }"""
            )
            writer.start()
            writer.join(60)  # the whole session, in real time
            page.get_by_text("(finished)").wait_for(timeout=20_000)
            shown = {int(stamp) for stamp, _ in page.evaluate("window.shown")} - {0}
            assert len(shown) > 10 and len(view.latency_ms) > 50  # the page kept showing newer messages
            # the last frame: the glove contacts of the session's newest data, as the contacts stage thresholds them
            taxels = catalog.query(
                layout, f"SELECT t, \"values\" FROM taxels WHERE recording_id = '{demo.recording_id}' ORDER BY t"
            ).to_pydict()
            t = np.asarray(taxels["t"])
            recent = t >= t[-1] - 8.0
            expected, _, _ = glove_contacts(
                t[recent] - t[recent][0], np.asarray(taxels["values"])[recent], ContactsConfig()
            )
            assert _regions_on(page, "human") == {r for r, on in zip(HUMAN_REGIONS, expected[-1], strict=True) if on}
    finally:
        stop.set()


def test_a_followed_file_that_turns_corrupt_leaves_the_view_serving_what_it_had(pick_demo, tmp_path) -> None:
    from touch2robot.view.follow import LiveSession, replay_in_real_time

    layout, demo = pick_demo
    recorded = tmp_path / "recorded.mcap"  # as a recorder writes it: one record a message, no chunks
    replay_in_real_time(layout.recordings / demo.file_name, recorded, threading.Event(), speed=50.0)
    source = recorded.read_bytes()
    growing = tmp_path / "live.mcap"
    cut = 8  # past the magic, record by record (opcode, length, content) to the first boundary after half
    while cut < len(source) // 2:
        cut += 9 + int.from_bytes(source[cut + 1 : cut + 9], "little")
    growing.write_bytes(source[:cut])
    session = LiveSession(growing)
    with _served(layout, demo, live=session) as (view, url), _page(url) as page:
        page.wait_for_function("document.querySelector('#contact-panel').dataset.stamp !== '0'", timeout=20_000)
        before = page.locator("#contact-panel").get_attribute("data-stamp")
        with open(growing, "ab") as f:
            f.write(b"\x05" + (1 << 40).to_bytes(8, "little"))  # a record claiming a terabyte
        page.get_by_text("corrupt record").wait_for(timeout=20_000)
        assert page.locator("#contact-panel").get_attribute("data-stamp") == before
        assert view.live is None


# ---------------------------------------------------------------------------------------------- command


def test_the_command_refuses_an_unknown_recording_and_a_port_in_use_with_a_clear_message(pick_demo) -> None:
    layout, demo = pick_demo
    command = [sys.executable, "-m", "app.cli", "view", "--data", str(layout.root)]
    unknown = subprocess.run([*command, "no-such-id"], capture_output=True, text=True, timeout=120)
    assert unknown.returncode == 2 and "'no-such-id' is not in the lake's recordings" in unknown.stdout
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        taken = subprocess.run(
            [*command, demo.recording_id, "--port", str(port)], capture_output=True, text=True, timeout=120
        )
    assert taken.returncode == 2 and f"port {port} on 127.0.0.1 is in use" in taken.stdout
    listing = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert listing.returncode == 0 and demo.file_name in listing.stdout


def test_a_replay_exports_as_a_rerun_recording_with_both_sides_and_the_contacts(pick_demo, tmp_path) -> None:
    from rerun.experimental import RrdReader

    from touch2robot.view.export import write_rrd

    layout, demo = pick_demo
    rollout = load_trajectory(layout, next(c for c in demo.trajectories if c.key == ROLLOUT))
    path = write_rrd(demo, rollout, tmp_path / "pick.rrd")
    store = RrdReader(path).store()
    entities = set(store.schema().entity_paths())
    assert {"/robot/palm/P1_pad", "/robot/if_ds/T2_pad", "/human/skeleton", "/human/glove"} <= entities
    assert {
        f"/contacts/{side}/{r}"
        for side, regions in (("human", HUMAN_REGIONS), ("robot", ROBOT_REGIONS))
        for r in regions
    } <= entities
    rows = [
        (t, v[0])
        for chunk in store.stream()
        if chunk.entity_path == "/contacts/robot/T2"
        for t, v in zip(
            chunk.to_record_batch().column("t_ref").to_pylist(),
            chunk.to_record_batch().column("Scalars:scalars").to_pylist(),
            strict=True,
        )
    ]
    t = np.array([r[0].total_seconds() if hasattr(r[0], "total_seconds") else r[0] * 1e-9 for r in rows])
    values = np.array([r[1] for r in rows])
    expected = np.array([rollout.contacts_at(float(x))[ROBOT_REGIONS.index("T2")] for x in t], float)
    assert len(values) > 20 and np.array_equal(values, expected)
    assert values.max() == 1.0 and values.min() == 0.0  # T2 touches during STEPS_TOUCHING only


# ---------------------------------------------------------------------------------------------- protocol


def test_the_protocol_counterbalances_refuses_bad_ids_and_ratings_and_keeps_the_file_whole(tmp_path) -> None:
    path = tmp_path / "ratings_study.csv"
    orders = []
    for k, participant in enumerate(("a1", "b2", "c3", "d4")):
        session = study.start(path, participant, "rec")
        orders.append(session.order)
        for _ in range(2):
            session.answer({q: 1 + (k + i) % 7 for i, q in enumerate(study.QUESTIONNAIRE)})
        assert study.save(path, session) == 8
    assert orders == [study.condition_order(0), study.condition_order(1)] * 2 and orders[0] != orders[1]
    with pytest.raises(study.StudyError, match=r"already in ratings_study\.csv"):
        study.start(path, "b2", "rec")
    with pytest.raises(study.StudyError, match=r"participant id '\.\./x'"):
        study.start(path, "../x", "rec")
    session = study.start(path, "e5", "rec")
    with pytest.raises(study.StudyError, match=r"Q3: rating 9 is not an integer in 1..7"):
        session.answer({"Q1": 1, "Q2": 2, "Q3": 9, "Q4": 4})
    with pytest.raises(study.StudyError, match="has not answered"):
        study.save(path, session)
    from touch2robot.stats import user_study

    assert len(user_study(study.read_ratings(path)).tests) == 4  # the file is what the statistics read


def test_synthetic_ratings_are_reported_only_while_no_real_ratings_have_statistics() -> None:
    from touch2robot.evaluate import reported_studies

    synthetic = {"path": "ratings_SYNTHETIC.csv", "synthetic": True, "rows": [{"q": 1}]}
    real = {"path": "ratings_study.csv", "synthetic": False, "rows": [{"q": 1}]}
    broken = {"path": "ratings_typo.csv", "synthetic": False, "rows": []}
    assert reported_studies([synthetic]) == [synthetic]
    assert reported_studies([synthetic, broken]) == [synthetic, broken]
    assert reported_studies([synthetic, real, broken]) == [real, broken]
