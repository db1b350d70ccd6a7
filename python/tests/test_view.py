"""`sonoslice view` and `live ... --view` in a real browser: Debian's headless Chromium driven by
selenium. Every figure on the page is checked against an independent computation here: the
planes against the library's slices of the same planes, the image at pose k against what
`sonoslice slice` writes, the fan outline against this file's own perspective projection."""
import base64
import json
import os
import shutil
import signal
import socket
import subprocess
import time
import warnings

import numpy as np
import pytest

import sonoslice
from conftest import DATA

# CI installs the browser (scripts/install-deps.sh) and sets SONOSLICE_REQUIRE_BROWSER=1: there a
# missing browser fails instead of skipping.
REQUIRE = os.environ.get("SONOSLICE_REQUIRE_BROWSER") == "1"
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
CHROMEDRIVER = shutil.which("chromedriver") or "/usr/bin/chromedriver"
try:
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
except ImportError:  # pragma: no cover
    webdriver = None
if webdriver is None or not (os.access(CHROMIUM, os.X_OK) and os.access(CHROMEDRIVER, os.X_OK)):
    if REQUIRE:
        raise RuntimeError("SONOSLICE_REQUIRE_BROWSER=1 but selenium, chromium or chromedriver is missing")
    pytest.skip("needs selenium, chromium and chromium-driver", allow_module_level=True)

LUS = os.path.join(DATA, "fanslicer", "models_intensity_LUS_config.json")  # W1 at downsampling 2
SEQUENCE = os.path.join(DATA, "plus", "BoneUltrasound_L14.igs.mha")
CONFIG = os.path.join(DATA, "plus", "BoneUltrasound_L14_config.xml")
NWIRE = os.path.join(DATA, "plus", "NwirePhantomFreehandReconstructed.mha")
SELECTED = (255, 230, 0)  # the selected pose's outline (docs/view.md)
SCREENSHOTS = os.environ.get("SONOSLICE_SCREENSHOTS")  # a folder: the docs' pictures go there


# ------------------------------------------------------------------------------------ fixtures --

@pytest.fixture(scope="module")
def phantom_dir(cli, tmp_path_factory):
    d = tmp_path_factory.mktemp("phantom")
    subprocess.run([cli, "phantom", str(d), "--size", "small", "--poses", "16", "-q"], check=True)
    return d


class Viewer:
    """A running `sonoslice view` (or live command with --view) and its address."""

    def __init__(self, args, marker="sonoslice view: "):
        self.process = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.lines = []
        while True:
            line = self.process.stdout.readline()
            if not line:
                raise RuntimeError(f"{args[1]} did not start: {self.process.stderr.read()}")
            self.lines.append(line)
            if line.startswith(marker) and "http://" in line:
                self.url = line.split(": ", 1)[1].strip()
                return

    def stop(self):
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
        assert self.process.wait(30) == 0, self.process.stderr.read()


def start_view(cli, *args):
    return Viewer([cli, "view", "--no-browser", *map(str, args)])


def chromium(*extra, network_log=True):
    """Debian's Chromium, headless, with its console log and (`network_log`) its network log kept;
    the network log costs the page about a fifth of its speed, so the timed runs leave it off."""
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for a in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--window-size=1400,900",
              "--force-device-scale-factor=1", *extra):
        options.add_argument(a)
    logs = {"browser": "ALL", "performance": "ALL"} if network_log else {"browser": "ALL"}
    options.set_capability("goog:loggingPrefs", logs)
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    driver.set_script_timeout(60)
    return driver


@pytest.fixture(scope="module")
def browser():
    driver = chromium()
    yield driver
    driver.quit()


def open_page(driver, url, timeout=20):
    driver.get("about:blank")
    for log in driver.log_types:  # start each page with empty logs
        driver.get_log(log)
    driver.get(url)
    t0 = time.time()
    while not driver.execute_script("return !!(window.sonosliceView && window.sonosliceView.ready)"):
        assert time.time() - t0 < timeout, f"the page at {url} never became ready: {console(driver)}"
        time.sleep(0.02)
    return time.time() - t0


def console(driver):
    return [e for e in driver.get_log("browser")]


def assert_clean(driver, url):
    """No console error, and every request the page made went to the viewer itself."""
    errors = [e["message"] for e in console(driver) if e["level"] == "SEVERE"]
    assert not errors, errors
    requests = []
    for entry in driver.get_log("performance"):
        m = json.loads(entry["message"])["message"]
        if m["method"] == "Network.requestWillBeSent":
            requests.append(m["params"]["request"]["url"])
    assert requests, "no request was logged"
    outside = [r for r in requests if not (r.startswith(url) or r.startswith(("data:", "blob:")))]
    assert not outside, outside


def assert_clean_by_resource_timing(driver, url):
    """assert_clean without the network log: the page's own record of what it fetched."""
    errors = [e["message"] for e in console(driver) if e["level"] == "SEVERE"]
    assert not errors, errors
    names = driver.execute_script("return performance.getEntriesByType('resource').map(e => e.name)")
    assert names, "no request was recorded"
    outside = [n for n in names if not (n.startswith(url) or n.startswith(("data:", "blob:")))]
    assert not outside, outside


def call(driver, expression):
    """Awaits the page's promise `expression` (a hook of window.sonosliceView)."""
    result = driver.execute_async_script(
        "const done = arguments[arguments.length - 1];"
        f"Promise.resolve({expression}).then(() => done('ok'), e => done('error: ' + e));")
    assert result == "ok", result


def canvas_pixels(driver, canvas_id):
    """(H, W, 4) uint8 of a canvas as drawn (a WebGL canvas through a 2-D copy)."""
    b64, w, h = driver.execute_script("""
        const c = document.getElementById(arguments[0]);
        let ctx = c.getContext('2d');
        if (!ctx) {
          const copy = document.createElement('canvas');
          copy.width = c.width; copy.height = c.height;
          ctx = copy.getContext('2d');
          ctx.drawImage(c, 0, 0);
        }
        const d = ctx.getImageData(0, 0, c.width, c.height).data;
        let s = '';
        for (let i = 0; i < d.length; i += 8192) s += String.fromCharCode.apply(null, d.subarray(i, i + 8192));
        return [btoa(s), c.width, c.height];""", canvas_id)
    return np.frombuffer(base64.b64decode(b64), np.uint8).reshape(h, w, 4)


def windowed(values, level, width):
    """The page's (and the PNG writers') window: (v − (L − W/2))·255/W, clamped, rounded."""
    g = (values.astype(np.float64) - (level - width / 2)) * (255.0 / width)
    g = np.where(np.isnan(g), 0, np.clip(g, 0, 255))
    return np.floor(g + 0.5).astype(np.uint8)


def plane_pose(plane, position):
    u, v = np.array(plane["u"]), np.array(plane["v"])
    o = np.array(plane["origin"], float)
    o[plane["axis"]] = position
    t = np.eye(4)
    t[:3, 0], t[:3, 1], t[:3, 2], t[:3, 3] = u, v, np.cross(u, v), o
    return t


def reference_plane(volume, plane, position, interpolation="linear"):
    """The plane as the library slices it: a linear probe whose pixels are the plane's."""
    probe = sonoslice.Probe.linear(plane["width"], plane["height"], plane["spacing"], origin_mm=(0.0, 0.0))
    return sonoslice.Slicer(volume, probe, interpolation=interpolation).slice(plane_pose(plane, position))[0]


def check_planes(driver, volume, level, width):
    scene = driver.execute_script("return window.sonosliceView.scene")
    call(driver, f"window.sonosliceView.setWindow({level}, {width})")
    positions = driver.execute_script("return window.sonosliceView.state.positions")
    for plane in scene["planes"]:
        a = plane["axis"]
        shown = canvas_pixels(driver, f"plane-{a}")
        expected = windowed(reference_plane(volume, plane, positions[a]), level, width)
        assert shown.shape[:2] == expected.shape
        np.testing.assert_array_equal(shown[..., 0], expected, err_msg=f"plane {plane['name']}")
        assert (shown[..., 3] == 255).all()
    return scene


def screenshot(driver, name):
    if SCREENSHOTS:
        os.makedirs(SCREENSHOTS, exist_ok=True)
        driver.save_screenshot(os.path.join(SCREENSHOTS, name))


# --------------------------------------------------------------------------------------- tests --

def test_view_planes_images_and_fans_on_the_phantom(cli, phantom_dir, browser, tmp_path):
    ct, labels = phantom_dir / "ct.nii.gz", phantom_dir / "labels.nii.gz"
    poses = phantom_dir / "surface_poses.txt"
    viewer = start_view(cli, "--volume", ct, "--labels", labels, "--probe", LUS, "--downsampling", 2,
                        "--poses", poses)
    try:
        assert viewer.url.startswith("http://127.0.0.1:")
        open_page(browser, viewer.url)
        volume = sonoslice.Volume.from_file(ct)
        # 1. The three planes, scrolled, equal the library's slices of the same planes.
        call(browser, "window.sonosliceView.setLabels(false)")
        scene = check_planes(browser, volume, 40, 400)
        for plane in scene["planes"]:
            p = plane["position"] + 7 * plane["step"]
            call(browser, f"window.sonosliceView.setPlane({plane['axis']}, {p})")
        check_planes(browser, volume, -200, 1500)
        call(browser, "window.sonosliceView.setLabels(true)")
        screenshot(browser, "view_phantom.png")

        # 2. The image at pose k is the image `sonoslice slice` writes for pose k.
        stack = tmp_path / "slices.npy"
        subprocess.run([cli, "slice", "--volume", str(ct), "--probe", LUS, "--downsampling", "2",
                        "--poses", str(poses), "--out", str(stack), "-q"], check=True)
        images = np.load(stack)
        call(browser, "window.sonosliceView.setImageWindow(40, 400)")
        for k in (0, 5, len(images) - 1):
            call(browser, f"window.sonosliceView.setPose({k})")
            shown = canvas_pixels(browser, "image")
            np.testing.assert_array_equal(shown[..., 0], windowed(images[k], 40, 400), err_msg=f"pose {k}")

        # 3. The selected fan's corners are drawn where they project (this file's projection).
        assert browser.execute_script("return window.sonosliceView.webgl") is True
        k = 5
        call(browser, f"window.sonosliceView.setPose({k})")
        pose = np.asarray(sonoslice.read_poses(str(poses)))[k]
        corners = [pose @ np.array([x, y, 0.0, 1.0]) for x, y in scene["probe"]["corners"]]
        centre = np.mean(corners, axis=0)[:3]
        camera = {"eye": (centre + 260 * pose[:3, 2] - 60 * pose[:3, 1]).tolist(),
                  "target": centre.tolist(), "up": (-pose[:3, 1]).tolist(), "fovDeg": 40}
        browser.execute_script(f"window.sonosliceView.setCamera({json.dumps(camera)})")
        gl = canvas_pixels(browser, "scene3d")
        h, w = gl.shape[:2]
        yellow = np.all(gl[..., :3] == SELECTED, axis=-1)
        assert yellow.sum() > 50, "the selected fan's outline is not drawn"
        for corner in corners:
            x, y = project(camera, corner[:3], w, h)
            assert 2 <= x < w - 2 and 2 <= y < h - 2, (x, y)
            window = yellow[int(round(y)) - 2:int(round(y)) + 3, int(round(x)) - 2:int(round(x)) + 3]
            assert window.any(), f"no outline pixel within 2 px of the corner projected at ({x:.1f}, {y:.1f})"
        screenshot(browser, "view_fan.png")
        assert_clean(browser, viewer.url)
    finally:
        viewer.stop()


def project(camera, point, width, height):
    """OpenGL's perspective(fovY, aspect) · lookAt(eye, target, up), to window pixels from the top."""
    eye, target, up = (np.array(camera[k], float) for k in ("eye", "target", "up"))
    f = (target - eye) / np.linalg.norm(target - eye)
    s = np.cross(f, up)
    s /= np.linalg.norm(s)
    u = np.cross(s, f)
    view = np.eye(4)
    view[0, :3], view[1, :3], view[2, :3] = s, u, -f
    view[:3, 3] = -view[:3, :3] @ eye
    t = 1 / np.tan(np.radians(camera["fovDeg"]) / 2)
    clip = view @ np.append(point, 1.0)
    ndc_x = t / (width / height) * clip[0] / -clip[2]
    ndc_y = t * clip[1] / -clip[2]
    return (ndc_x + 1) / 2 * width, (1 - ndc_y) / 2 * height


def test_view_compound_volume_of_a_plus_sweep(cli, browser):
    viewer = start_view(cli, "--compound", NWIRE)
    try:
        open_page(browser, viewer.url)
        check_planes(browser, sonoslice.Volume.from_file(NWIRE), 127.5, 255)
        screenshot(browser, "view_nwire.png")
        assert_clean(browser, viewer.url)
    finally:
        viewer.stop()


def test_a_page_served_on_a_network_address_needs_its_token(cli, browser):
    import urllib.error
    import urllib.request
    viewer = start_view(cli, "--compound", NWIRE, "--host", "0.0.0.0")
    try:
        base, _, token = viewer.url.partition("?token=")
        assert len(token) == 32 and base.endswith("/"), viewer.url
        for path in ("", "api/scene", "view.js", "api/plane?axis=0&pos=0", "?token=" + "0" * 32):
            with pytest.raises(urllib.error.HTTPError) as e:
                urllib.request.urlopen(base + path, timeout=10)
            assert e.value.code == 403, path
        # The printed URL opens the page; the cookie it gets carries every later request.
        open_page(browser, viewer.url)
        check_planes(browser, sonoslice.Volume.from_file(NWIRE), 127.5, 255)
        assert_clean(browser, base)
    finally:
        viewer.stop()


def test_planes_and_images_without_webgl(cli, phantom_dir):
    driver = chromium("--disable-webgl", "--disable-3d-apis")
    ct = phantom_dir / "ct.nii.gz"
    viewer = start_view(cli, "--volume", ct, "--probe", LUS, "--downsampling", 2,
                        "--poses", phantom_dir / "surface_poses.txt")
    try:
        open_page(driver, viewer.url)
        assert driver.execute_script("return window.sonosliceView.webgl") is False
        check_planes(driver, sonoslice.Volume.from_file(ct), 40, 400)
        call(driver, "window.sonosliceView.setPose(2)")
        assert canvas_pixels(driver, "image")[..., 0].any()
    finally:
        viewer.stop()
        driver.quit()


def test_bad_view_inputs_are_named(cli, tmp_path):
    r = subprocess.run([cli, "view", "--no-browser", "--volume", str(tmp_path / "missing.nii")],
                       capture_output=True, text=True, timeout=30)
    assert r.returncode == 1 and "missing.nii" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    r = subprocess.run([cli, "view", "--no-browser"], capture_output=True, text=True, timeout=30)
    assert r.returncode == 2 and "nothing to show" in r.stderr
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        r = subprocess.run([cli, "view", "--no-browser", "--compound", NWIRE, "--port", str(port)],
                           capture_output=True, text=True, timeout=30)
    assert r.returncode == 1 and str(port) in r.stderr
    # A port out of range is bad input (1) before anything loads, as `live ... --view` says it.
    r = subprocess.run([cli, "view", "--no-browser", "--compound", str(tmp_path / "missing.nii"), "--port", "70000"],
                       capture_output=True, text=True, timeout=30)
    assert (r.returncode, r.stderr) == (1, "sonoslice: error: --port 70000: expected a port 0-65535\n"), r.stderr


def test_three_planes_at_once_are_the_three_planes(cli, phantom_dir):
    import urllib.request
    viewer = start_view(cli, "--volume", phantom_dir / "ct.nii.gz", "--labels", phantom_dir / "labels.nii.gz")
    try:
        get = lambda path: urllib.request.urlopen(viewer.url + path, timeout=10).read()  # noqa: E731
        scene = json.loads(get("api/scene"))
        # Off-centre positions, one between two voxel layers.
        pos = [p["position"] + k * 7.25 for k, p in enumerate(scene["planes"])]
        for layer in ("volume", "labels"):
            together = get(f"api/planes?pos={pos[0]!r},{pos[1]!r},{pos[2]!r}&layer={layer}")
            one_by_one = b"".join(get(f"api/plane?axis={a}&pos={pos[a]!r}&layer={layer}") for a in range(3))
            assert len(together) == 4 * sum(p["width"] * p["height"] for p in scene["planes"])
            assert together == one_by_one, layer
    finally:
        viewer.stop()


def test_server_answers_bad_requests_and_keeps_serving(cli, phantom_dir):
    import urllib.error
    import urllib.request
    viewer = start_view(cli, "--volume", phantom_dir / "ct.nii.gz", "--probe", LUS, "--downsampling", 2,
                        "--poses", phantom_dir / "surface_poses.txt")
    try:
        for bad, message in (("api/plane?axis=7&pos=0", "plane: axis 0..2"),
                             ("api/plane?axis=1&pos=nan", "plane: pos 'nan' is not a finite number"),
                             ("api/plane?axis=x&pos=1", "plane: axis 'x' is not a whole number"),
                             ("api/plane?axis=1abc&pos=0", "plane: axis '1abc' is not a whole number"),
                             ("api/plane?axis=0&pos=5mm", "plane: pos '5mm' is not a finite number"),
                             ("api/plane?axis=0&pos=0x10", "plane: pos '0x10' is not a finite number"),
                             ("api/plane?axis=%201&pos=0", "plane: axis ' 1' is not a whole number"),
                             ("api/plane?axis=0&pos=1e308", "plane: pos '1e308' is beyond any scanner"),
                             ("api/plane", "plane: axis '' is not a whole number"),
                             ("api/image?pose=100000", "image: pose 100000 out of range"),
                             ("api/image?pose=-1", "image: pose -1 out of range"),
                             ("api/image?pose=1e3", "image: pose '1e3' is not a whole number"),
                             ("api/image?pose=2.7", "image: pose '2.7' is not a whole number"),
                             ("api/image?matrix=1,2,3", "image: matrix '1,2,3': 16 finite numbers"),
                             ("api/image?matrix=" + ",".join(["1"] * 17), "image: matrix"),
                             ("api/planes?pos=1,2", "planes: pos '1,2': 3 finite numbers"),
                             ("api/planes?pos=1,2,3,", "planes: pos '1,2,3,': 3 finite numbers"),
                             ("api/planes?pos=0,0,1e308", "planes: pos '0,0,1e308' is beyond any scanner"),
                             ("api/planes?pos=0,0,0&layer=x", "planes: layer 'x': volume or labels"),
                             ("api/planes?pos=0,0,0&layer=labels", "planes: no labels to show"),
                             ("api/planes", "planes: pos '': 3 finite numbers"),
                             ("api/image?matrix=1,,0", "image: matrix '1,,0': 16 finite numbers"),
                             ("api/image?matrix=" + ",".join(["nan"] * 16), "image: matrix"),
                             ("api/mesh/3", "mesh"), ("api/mesh/99999999999999999999", "view: 404: no such page"),
                             ("nope", "view: 404: no such page '/nope'")):
            with pytest.raises(urllib.error.HTTPError) as e:
                urllib.request.urlopen(viewer.url + bad, timeout=10)
            assert e.value.code in (400, 404), bad
            assert e.value.read().decode().startswith(message), bad
        # Only GET: other methods and bodies are refused before a body is read.
        for method, headers, code in (("POST", {}, 405), ("DELETE", {}, 405),
                                      ("GET", {"Transfer-Encoding": "chunked"}, 413)):
            request = urllib.request.Request(viewer.url + "api/scene", method=method, headers=headers,
                                             data=b"x" * 1000 if method == "POST" else None)
            with pytest.raises(urllib.error.HTTPError) as e:
                urllib.request.urlopen(request, timeout=10)
            assert e.value.code == code, method
        # A page of another site that re-points its name at 127.0.0.1 (DNS rebinding) is refused,
        # also a name that merely begins like a loopback address; the loopback names are answered.
        for host, code in (("attacker.example:80", 403), ("127.0.0.1.attacker.example", 403),
                           ("127.attacker.example:80", 403), ("localhost", 200), ("127.0.0.1", 200),
                           ("127.1.2.3:8", 200)):
            request = urllib.request.Request(viewer.url + "api/scene", headers={"Host": host})
            try:
                assert urllib.request.urlopen(request, timeout=10).status == code, host
            except urllib.error.HTTPError as e:
                assert e.code == code, host
        body = urllib.request.urlopen(viewer.url + "api/image?pose=0", timeout=10).read()
        assert len(body) == 4 * 334 * 272
        # A probe is placed rigidly: a scaled or mirrored matrix is refused, as live slice refuses it.
        for matrix in ("2,0,0,0,0,2,0,0,0,0,2,0,0,0,0,1", "-1,0,0,0,0,1,0,0,0,0,1,0,0,0,0,1"):
            with pytest.raises(urllib.error.HTTPError) as e:
                urllib.request.urlopen(viewer.url + "api/image?matrix=" + matrix, timeout=10)
            assert e.value.code == 400 and "image: matrix: not a rigid frame" in e.value.read().decode(), matrix
        # What cpp-httplib turns away, and what a GET must not carry, answered in one line.
        port = int(viewer.url.rsplit(":", 1)[1].strip("/"))
        for request, status, line in (
                (b"GET /" + b"a" * 200000 + b" HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n", b"414", b"view: 414: the URI is too long"),
                (b"GET /api/scene HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: 5\r\n\r\nhello", b"413",
                 b"view: a request body is not taken here"),
                (b"GET /api/scene HTTP/1.1\r\nHost: 127.0.0.1\r\nHost: evil.example\r\n\r\n", b"400",
                 b"view: more than one Host header")):
            with socket.create_connection(("127.0.0.1", port), timeout=10) as raw:
                raw.sendall(request)
                answer = b""
                while not answer.endswith(line):
                    chunk = raw.recv(65536)
                    if not chunk:
                        break
                    answer += chunk
            assert answer.split(b"\r\n", 1)[0].split(b" ")[1] == status and answer.endswith(line), answer[-200:]
    finally:
        viewer.stop()


def test_images_of_a_stack_or_a_png_folder_are_served_as_given(cli, phantom_dir, tmp_path):
    import urllib.request
    poses = phantom_dir / "surface_poses.txt"
    common = ["--volume", str(phantom_dir / "ct.nii.gz"), "--probe", LUS, "--downsampling", "2",
              "--poses", str(poses)]
    subprocess.run([cli, "slice", *common, "--out", str(tmp_path / "s.npy"), "-q"], check=True)
    subprocess.run([cli, "slice", *common, "--out", str(tmp_path / "png") + "/", "--window", "40,400", "-q"],
                   check=True)
    stack = np.load(tmp_path / "s.npy")
    for given, expected in ((tmp_path / "s.npy", stack), (tmp_path / "png", windowed(stack, 40, 400))):
        viewer = start_view(cli, *common, "--images", given)
        try:
            for k in (0, len(stack) - 1):
                body = urllib.request.urlopen(viewer.url + f"api/image?pose={k}", timeout=10).read()
                shown = np.frombuffer(body, np.float32).reshape(stack.shape[1:])
                np.testing.assert_array_equal(shown, expected[k], err_msg=f"{given} pose {k}")
        finally:
            viewer.stop()


@pytest.fixture
def timed_browser():
    """A browser without the network log, for the tests that time the page."""
    driver = chromium(network_log=False)
    yield driver
    driver.quit()


@pytest.mark.alone
def test_live_compound_view_updates_and_ends_on_the_offline_volume(cli, timed_browser, tmp_path):
    browser = timed_browser
    pyigtl = pytest.importorskip("pyigtl")
    from sonoslice.live import plus_frames
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the configuration's deprecated attribute
        frames = list(plus_frames(SEQUENCE, CONFIG))
    out, record = tmp_path / "live.mha", tmp_path / "record.igs.mha"
    # The grid given, as a PlusServer configuration gives it (OutputOrigin/OutputExtent).
    g = sonoslice.grid_around(np.stack([m for _, m, _ in frames]), frames[0][0].shape, 0.5)
    grid = ["--origin", ",".join(f"{v:.17g}" for v in g.origin), "--extent", ",".join(map(str, g.dims))]
    viewer = Viewer([cli, "live", "compound", "--listen", "127.0.0.1:0", "--config", CONFIG, *grid,
                     "--out", str(out), "--record", str(record), "--max-frames", str(4 * len(frames)),
                     "--view", "0"],
                    marker="sonoslice live compound: ")
    port = int(viewer.lines[0].rsplit(":", 1)[1])
    try:
        open_page(browser, viewer.url)
        browser.execute_script("performance.setResourceTimingBufferSize(1000000)")  # every poll kept
        sock = socket.create_connection(("127.0.0.1", port), timeout=30)
        samples = []
        # The sweep four times over at 30 frames/s; the page is sampled as it goes.
        t0 = time.time()
        for i in range(4 * len(frames)):
            pixels, matrix, _ = frames[i % len(frames)]
            m = pyigtl.ImageMessage(pixels[np.newaxis], ijk_to_world_matrix=matrix, timestamp=i / 30,
                                    device_name="Image_Reference")
            sock.sendall(m.pack())
            if i % 5 == 0:
                samples.append((time.time(), *browser.execute_script(
                    "const v = window.sonosliceView;"
                    "return [v.stats.liveUpdates, Number(document.getElementById('frame-counter').textContent),"
                    " v.stats.framesShown]")))
            time.sleep(max(0.0, t0 + (i + 1) / 30 - time.time()))
        # While the sender streams, the planes and the counter change ≥ 10 times a second.
        (ta, ua, fa, sa), (tb, ub, fb, sb) = samples[len(samples) // 4], samples[-1]
        rate = (ub - ua) / (tb - ta)
        print(f"live view: {rate:.1f} plane updates/s and {(sb - sa) / (tb - ta):.1f} frames shown/s "
              "while streaming 30 frames/s")
        assert rate >= 10, samples
        assert fb > fa and sb > sa  # the counter, and the newest frame drawn in its place
        screenshot(browser, "view_live.png")
        # The run ends (--max-frames); the page then shows the volume `compound` makes offline.
        line = viewer.process.stderr.readline()
        while "the run ended" not in line:
            assert line, "the live run did not end"
            line = viewer.process.stderr.readline()
        time.sleep(1.5)  # the page's slower poll after the end picks up the final volume
        assert browser.execute_script("return Number(document.getElementById('frame-counter').textContent)") \
            == 4 * len(frames)
        # The offline volume: `compound` of the frames the run recorded.
        offline = tmp_path / "offline.mha"
        subprocess.run([cli, "compound", "--sequence", str(record), "--config", CONFIG, "-q", *grid,
                        "--out", str(offline)], check=True)
        check_planes(browser, sonoslice.Volume.from_file(offline), 127.5, 255)
        sock.close()
        assert_clean_by_resource_timing(browser, viewer.url)
    finally:
        viewer.stop()


def test_simulated_image_at_a_pose_is_what_simulate_writes(cli, phantom_dir, tmp_path):
    import urllib.request
    ct, poses = phantom_dir / "ct.nii.gz", phantom_dir / "surface_poses.txt"
    sim = tmp_path / "sim.npy"
    subprocess.run([cli, "simulate", "--volume", str(ct), "--probe", LUS, "--downsampling", "2", "--poses",
                    str(poses), "--out", str(sim), "-q"], check=True)
    expected = np.load(sim)
    viewer = start_view(cli, "--volume", ct, "--probe", LUS, "--downsampling", 2, "--poses", poses, "--simulate")
    try:
        scene = json.loads(urllib.request.urlopen(viewer.url + "api/scene", timeout=10).read())
        assert scene["image_source"] == "simulate" and scene["image_window"] == [127.5, 255.0]
        for k in (0, 7):
            body = urllib.request.urlopen(viewer.url + f"api/image?pose={k}", timeout=30).read()
            shown = np.frombuffer(body, np.float32).reshape(expected.shape[1:])
            np.testing.assert_array_equal(shown, expected[k].astype(np.float32))
    finally:
        viewer.stop()
