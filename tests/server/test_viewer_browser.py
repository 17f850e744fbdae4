"""The web viewer at /app in a real headless browser (Debian's chromium and chromedriver through selenium; never a
downloaded browser): it signs in, draws a seeded session's trajectory on the map and its timelines, updates an
open session live, logs no console error, and its screenshot shows the track and the timelines.

Skipped with the reason when /usr/bin/chromium or /usr/bin/chromedriver is absent (``.ci/run`` installs the
Debian packages ``chromium`` and ``chromium-driver`` where it can)."""

from __future__ import annotations

import base64
import os
import struct
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

CHROMIUM = "/usr/bin/chromium"
CHROMEDRIVER = "/usr/bin/chromedriver"

if not (os.path.exists(CHROMIUM) and os.path.exists(CHROMEDRIVER)):
    pytest.skip(f"browser test needs Debian's chromium and chromium-driver ({CHROMIUM}, {CHROMEDRIVER}): "
                "apt-get install chromium chromium-driver", allow_module_level=True)
selenium = pytest.importorskip("selenium", reason="browser test needs selenium (pip install -e '.[test]')")

from selenium import webdriver  # noqa: E402
from selenium.webdriver.chrome.service import Service  # noqa: E402
from selenium.webdriver.support.ui import WebDriverWait  # noqa: E402


def _png(rgb: tuple[int, int, int], size: int = 256) -> bytes:
    """A solid PNG (what a map tile server answers), written without an imaging library."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    raw = b"".join(b"\x00" + bytes(rgb) * size for _ in range(size))
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", size, size, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


TILE = "data:image/png;base64," + base64.b64encode(_png((232, 240, 226))).decode()  # a pale "land" tile, offline


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    """A server whose map tiles are a local image, a user, an anchored closed session of a synthetic walk and an
    unanchored open one holding the first half of another."""
    from clients.commands.demo import LocalServer
    from clients.sdk import PednavClient
    from clients.simulators import FootSensorSimulator
    from clients.synth import synthesize
    from server import crud

    os.environ["PEDNAV_MAP_TILE_URL"] = TILE
    try:
        db = tmp_path_factory.mktemp("viewer") / "pednav.db"
        srv = LocalServer(f"sqlite:///{db}")
    finally:
        del os.environ["PEDNAV_MAP_TILE_URL"]
    with srv:
        with srv.app.state.sessionmaker() as s:
            _, token = crud.create_user(s, "viewer")
            s.commit()
        api = PednavClient(srv.url, token)
        rec = synthesize("walk", seed=3)
        res = FootSensorSimulator(rec, batch_seconds=None).run(
            api, start={"latitude_deg": 33.6405, "longitude_deg": -117.8443, "altitude_m": 15.0})
        live_rec = synthesize("walk", seed=5)
        live = api.start_session("foot")
        b = live_rec.batch
        t0 = int(b.t_start_ns)
        cuts = [t0 + k * 10**9 for k in range(int((int(b.t_end_ns) - t0) / 1e9) + 2)]
        pieces = [b.time_slice(a, c) for a, c in zip(cuts[:-1], cuts[1:])]
        half = len(pieces) // 2
        for k, piece in enumerate(pieces[:half]):
            api.upload(live["id"], k, piece)
        yield {"url": srv.url, "token": token, "closed": res.session_id, "open": live["id"], "api": api,
               "rest": list(enumerate(pieces))[half:], "n_closed": len(api.trajectory(res.session_id)["positions"])}
        api.close()
        if srv.app.state.host.pool is not None:
            srv.app.state.host.pool.shutdown()


@pytest.fixture(scope="module")
def browser(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Any]:
    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for a in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--no-first-run",
              "--disable-background-networking", "--disable-component-update", "--disable-sync", "--disable-quic",
              "--window-size=1300,1100", f"--user-data-dir={tmp_path_factory.mktemp('chromium-profile')}"):
        opts.add_argument(a)
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    drv = webdriver.Chrome(service=Service(executable_path=CHROMEDRIVER), options=opts)
    drv.set_page_load_timeout(60)
    yield drv
    drv.quit()


def _open(drv: Any, site: dict[str, Any], session: int) -> None:
    drv.get(site["url"] + "/app/")
    drv.execute_script("localStorage.setItem('pednav_token', arguments[0]);", site["token"])
    drv.get(f"{site['url']}/app/?session={session}")
    WebDriverWait(drv, 60).until(lambda d: d.execute_script(
        "return document.body.dataset.state === 'ready' && document.body.dataset.session === arguments[0];", str(session)))


def _console_errors(drv: Any) -> list[dict[str, Any]]:
    return [e for e in drv.get_log("browser") if e["level"] == "SEVERE"]


_INK = """
const c = document.getElementById(arguments[0]);
const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
let n = 0; for (let i = 3; i < d.length; i += 4) if (d[i] > 0) n++;
return [n, c.width * c.height, Number(c.dataset.drawn || 0)];
"""
TIMELINES = ("tl-behaviour", "tl-mode", "tl-gyro", "tl-rate")


def check_page(drv: Any, n_positions: int, tiles: bool) -> dict[str, Any]:
    """What a person must see: the track, a step per position, the map's base (tiles or grid), every timeline
    inked, the energy and profile tables filled. Raises AssertionError naming what is missing."""
    track = drv.execute_script("return Array.from(document.querySelectorAll('path.pednav-track')).map(p => p.getAttribute('d'));")
    assert len(track) == 1 and len(track[0] or "") > 50, f"trajectory layer missing: {track}"
    steps = drv.execute_script("return document.querySelectorAll('path.pednav-step').length;")
    assert steps == n_positions, f"{steps} step markers for {n_positions} positions"
    imgs = drv.execute_script("return document.querySelectorAll('#map img.leaflet-tile').length;")
    grid = drv.execute_script("return document.querySelectorAll('path.pednav-grid').length;")
    assert (imgs > 0 and grid == 0) if tiles else (grid > 4 and imgs == 0), f"tiles {imgs}, grid lines {grid}"
    for tl in TIMELINES:
        ink, area, drawn = drv.execute_script(_INK, tl)
        assert drawn > 0 and ink > 0.05 * area if tl != "tl-rate" else ink > 200, f"timeline {tl} is empty ({ink} px)"
    energy = drv.execute_script("return document.getElementById('energy').innerText;")
    assert "total" in energy and "mJ" in energy, energy
    profile = drv.execute_script("return document.getElementById('profile').innerText;")
    assert profile.strip(), "calibration profile table empty"
    return {"steps": steps, "energy": energy, "profile": profile}


def _screenshot_colours(png: bytes, path: Path) -> dict[str, float]:
    import io

    import matplotlib.image as mpimg

    path.write_bytes(png)
    img = (mpimg.imread(io.BytesIO(png), format="png")[..., :3] * 255).round().astype(int)
    flat = img.reshape(-1, 3)

    def share(rgb: tuple[int, int, int], tol: int = 30) -> float:
        return float(np.mean(np.all(np.abs(flat - np.array(rgb)) <= tol, axis=1)))

    return {"distinct": float(len(np.unique(flat[:: max(1, len(flat) // 200_000)], axis=0))),
            "zupt_red": share((214, 39, 40)), "walk_green": share((44, 160, 44)), "tile": share((232, 240, 226), 3)}


def test_viewer_draws_an_anchored_session(browser, site, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    _open(browser, site, site["closed"])
    seen = check_page(browser, site["n_closed"], tiles=True)
    assert "walk" in seen["profile"] and "heading deviation" in seen["profile"]  # the closed walk stored its profile
    north = browser.execute_script("return document.getElementById('north-note').innerText;")
    assert north.startswith("north:")
    assert _console_errors(browser) == []
    shot = tmp_path / "viewer-anchored.png"
    col = _screenshot_colours(browser.get_screenshot_as_png(), shot)
    assert col["distinct"] > 50 and col["zupt_red"] > 1e-4 and col["walk_green"] > 1e-4 and col["tile"] > 0.05, (col, shot)


def test_viewer_updates_an_open_session_live_on_a_metric_grid(browser, site, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    api = site["api"]
    before = len(api.trajectory(site["open"])["positions"])
    _open(browser, site, site["open"])
    check_page(browser, before, tiles=False)
    assert browser.execute_script("return !document.getElementById('live').hidden;")
    for k, piece in site["rest"]:
        api.upload(site["open"], k, piece)
    after = len(api.trajectory(site["open"])["positions"])
    assert after > before
    WebDriverWait(browser, 30).until(lambda d: d.execute_script(
        "return document.querySelectorAll('path.pednav-step').length;") == after)
    check_page(browser, after, tiles=False)
    assert _console_errors(browser) == []
    col = _screenshot_colours(browser.get_screenshot_as_png(), tmp_path / "viewer-live.png")
    assert col["distinct"] > 50 and col["zupt_red"] > 1e-4 and col["tile"] == 0.0, col


def test_a_wrong_token_is_refused_on_the_page(browser, site) -> None:  # type: ignore[no-untyped-def]
    browser.get(site["url"] + "/app/")
    browser.execute_script("localStorage.removeItem('pednav_token');")
    browser.get(site["url"] + "/app/")
    WebDriverWait(browser, 20).until(lambda d: d.execute_script("return document.body.dataset.state === 'signed-out';"))
    browser.find_element("id", "token").send_keys("pn_not-a-token")
    browser.find_element("css selector", "#signin button").click()
    WebDriverWait(browser, 20).until(lambda d: "refused" in d.find_element("id", "status").text)
    assert browser.execute_script("return document.getElementById('main').hidden;")
    # (the refused request itself is the one console entry Chromium logs here: a 401 response)
    assert all("401" in e["message"] for e in _console_errors(browser))


def test_check_page_fails_without_the_track_or_a_timeline(browser, site) -> None:  # type: ignore[no-untyped-def]
    """The page check can fail: with the trajectory layer or a timeline taken off the page it says which."""
    _open(browser, site, site["closed"])
    browser.execute_script("document.querySelector('path.pednav-track').remove();")
    with pytest.raises(AssertionError, match="trajectory layer missing"):
        check_page(browser, site["n_closed"], tiles=True)
    _open(browser, site, site["closed"])
    browser.execute_script("const c = document.getElementById('tl-gyro'); c.getContext('2d').clearRect(0, 0, c.width, c.height);")
    with pytest.raises(AssertionError, match="timeline tl-gyro is empty"):
        check_page(browser, site["n_closed"], tiles=True)
