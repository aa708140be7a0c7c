"""cloudbaking-server against an attacker's inputs: request heads counted alone (pipelines answered, a large
body 413, a large head 431), settings and environment refused in one line, coerced JSON refused, lights kept
to the scene's range, a bounded GI tree by default, and no absolute path in any answer."""

from __future__ import annotations

import json
import shutil
import socket
import subprocess
import time
from pathlib import Path

import httpx
import pytest
from fastapi.testclient import TestClient

from baseline_cloudbaking.server.app import create_app
from baseline_cloudbaking.server.cli import guard_hosts
from baseline_cloudbaking.server.errors import redact
from baseline_cloudbaking.server.settings import Settings
from baseline_cloudbaking.store import DEFAULT_BUDGET_BYTES, GITree
from tests.helpers.cli import Outcome, assert_error_line, check_user_error, run_main, run_script
from tests.helpers.cloud import gimap_body, server_process, write_scenes

TIMEOUT_S = 60.0


@pytest.fixture(scope="module")
def scenes_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_scenes(tmp_path_factory.mktemp("hardening_scenes"))


def read_until_closed(sock: socket.socket) -> bytes:
    sock.settimeout(TIMEOUT_S)
    chunks = []
    while chunk := sock.recv(1 << 16):
        chunks.append(chunk)
    return b"".join(chunks)


HEALTH = b"GET /v1/health HTTP/1.1\r\nhost: 127.0.0.1\r\n\r\n"


def test_only_the_bytes_of_one_request_head_count_against_the_head_limit(tmp_path: Path, scenes_dir: Path) -> None:
    with server_process(tmp_path / "store", scenes_dir) as url:
        address = url.removeprefix("http://").split(":")
        address = (address[0], int(address[1]))
        with socket.create_connection(address, timeout=TIMEOUT_S) as sock:  # 500 pipelined heads: 18 KiB in all
            sock.sendall(HEALTH * 500 + HEALTH.replace(b"\r\n\r\n", b"\r\nconnection: close\r\n\r\n"))
            answers = read_until_closed(sock)
        assert answers.count(b"HTTP/1.1 200") == 501 and b"HTTP/1.1 431" not in answers
        with socket.create_connection(address, timeout=TIMEOUT_S) as sock:  # a 1 MiB body: too large a body
            body = b"x" * (1 << 20)
            head = "POST /v1/gimap HTTP/1.1\r\nhost: 127.0.0.1\r\ncontent-type: application/json\r\n"
            head += f"content-length: {len(body)}"
            sock.sendall(head.encode() + b"\r\n\r\n")
            try:
                sock.sendall(body)
            except OSError:
                pass  # the server answered and closed before reading it all
            assert sock.recv(64).startswith(b"HTTP/1.1 413")
        two_heads = HEALTH.replace(b"\r\n\r\n", b"\r\nx-pad: " + b"a" * 15_000 + b"\r\n\r\n") * 2
        with socket.create_connection(address, timeout=TIMEOUT_S) as sock:  # two 15 KB heads, each within the limit
            sock.sendall(two_heads + HEALTH.replace(b"\r\n\r\n", b"\r\nconnection: close\r\n\r\n"))
            assert read_until_closed(sock).count(b"HTTP/1.1 200") == 3
        padded = HEALTH.replace(b"\r\n\r\n", b"\r\nx-pad: " + b"a" * 20_000 + b"\r\n\r\n")
        with socket.create_connection(address, timeout=TIMEOUT_S) as sock:  # a whole 20 KB head at once
            sock.sendall(padded)
            assert read_until_closed(sock).startswith(b"HTTP/1.1 431")
        with socket.create_connection(address, timeout=TIMEOUT_S) as sock:  # the same head, in pieces
            try:
                for i in range(0, len(padded), 4096):
                    sock.sendall(padded[i : i + 4096])
                    time.sleep(0.01)
            except OSError:
                pass  # answered and closed
            assert read_until_closed(sock).startswith(b"HTTP/1.1 431")
        assert httpx.get(f"{url}/v1/stats", timeout=TIMEOUT_S).json()["heads_too_large"] == 2


def test_on_loopback_a_host_that_names_another_server_is_400(tmp_path: Path, scenes_dir: Path) -> None:
    """DNS rebinding: a page of attacker.example whose name now resolves to 127.0.0.1 sends its own name as
    Host. Any port passes (clients reach the server through proxies); --allowed-hosts adds names, '*' any. A
    request with two Host headers is 400 whichever names this server."""
    cases = {
        "": {"attacker.example": 400, "attacker.example:80": 400, "127.0.0.1:9": 200, "localhost": 200, "[::1]": 200},
        "gi.example.org": {"gi.example.org": 200, "GI.example.org:8000": 200, "attacker.example": 400},
        "*": {"attacker.example": 200},
    }
    for allowed, hosts in cases.items():
        with server_process(tmp_path / "store", scenes_dir, *(["--allowed-hosts", allowed] if allowed else [])) as url:
            for host, status in hosts.items():
                r = httpx.get(f"{url}/v1/health", headers={"Host": host}, timeout=TIMEOUT_S)
                assert r.status_code == status, (allowed, host, r.text)
            if allowed != "*":  # a second Host is not looked past, whichever comes first
                address = url.removeprefix("http://").split(":")
                for pair in (("127.0.0.1", "attacker.example"), ("attacker.example", "127.0.0.1")):
                    head = "GET /v1/health HTTP/1.1\r\n" + "".join(f"host: {h}\r\n" for h in pair)
                    with socket.create_connection((address[0], int(address[1])), timeout=TIMEOUT_S) as sock:
                        sock.sendall(head.encode() + b"connection: close\r\n\r\n")
                        assert read_until_closed(sock).startswith(b"HTTP/1.1 400"), (allowed, pair)


def test_each_spec_the_server_skips_is_one_line_when_it_starts(tmp_path: Path, scenes_dir: Path) -> None:
    scenes = tmp_path / "scenes"
    shutil.copytree(scenes_dir, scenes)
    (scenes / "broken.toml").write_text("name = [")
    (scenes / "no_light.json").write_text(json.dumps({"name": "no_light", "objects": []}))
    (scenes / "two words.json").write_text("{}")
    (scenes / "notes.txt").write_text("not a spec")
    with server_process(tmp_path / "store", scenes) as url:
        assert httpx.get(f"{url}/v1/health", timeout=TIMEOUT_S).status_code == 200
    said = (tmp_path / "store.server.stderr").read_text().splitlines()
    prefix = "cloudbaking-server: --scenes: skipped "
    skipped = [line.removeprefix(prefix) for line in said if line.startswith(prefix)]
    assert [line.split(": ")[0] for line in skipped] == ["broken.toml", "no_light.json", "two words.json"], said
    assert "cannot parse" in skipped[0] and "light" in skipped[1] and "no scene name" in skipped[2]


def test_an_allowed_host_with_a_port_is_refused_in_one_line() -> None:
    with pytest.raises(ValueError, match="'gi.example.org:80' is not a host name"):
        Settings(allowed_hosts=("gi.example.org:80",))


def test_off_loopback_no_host_is_refused_unless_names_are_given(tmp_path: Path) -> None:
    """Listening on every interface, a server is reached by names it cannot know: no check, unless it is told
    which names are its own."""
    with socket.create_server(("127.0.0.1", 0)) as sock:
        for extra, status in (((), 200), (("gi.example.org",), 400)):
            app = create_app(Settings(store=tmp_path / "s"))
            guard_hosts(app, extra, "0.0.0.0", sock)
            with TestClient(app) as client:
                assert client.get("/v1/health", headers={"Host": "attacker.example"}).status_code == status


@pytest.fixture
def server_run(tmp_path: Path, capfd: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch):
    """``cloudbaking-server --store S --port 0 ARGS`` in-process (tests.helpers.cli.run_main) with the
    environment variables ``env`` set for the run alone."""

    def run(env: dict[str, str], *args: str) -> Outcome:
        with monkeypatch.context() as patch:
            for name, value in env.items():
                patch.setenv(name, value)
            argv = ["cloudbaking-server", "--store", str(tmp_path / "s"), "--port", "0", *args]
            return run_main(argv, tmp_path, patch, capfd)

    return run


def test_settings_from_the_environment_are_checked_in_one_line(server_run, tmp_path: Path) -> None:
    assert_error_line(server_run({"CLOUDBAKING_RESOLUTIONS": "abc"}), "CLOUDBAKING_RESOLUTIONS", "JSON")
    typo = server_run({"CLOUDBAKING_SPPP": "4"})
    assert_error_line(typo, "CLOUDBAKING_SPPP", "CLOUDBAKING_MAX_SPP", "CLOUDBAKING_BUDGET_BYTES")
    for name, value in (("BUDGET_BYTES", "0"), ("MAX_BODY_BYTES", str(10**12)), ("SEED", "-1")):
        assert_error_line(server_run({f"CLOUDBAKING_{name}": value}), f"CLOUDBAKING_{name}")
    assert_error_line(server_run({}, "--graceful-timeout-s", "inf"), "--graceful-timeout-s")
    assert not (tmp_path / "s").exists()


def test_every_setting_is_an_option_that_names_its_variable_and_overrides_it(monkeypatch: pytest.MonkeyPatch) -> None:
    """The settings are declared once: each is a cloudbaking-server option whose help is the setting's
    description with its default and variable, and the option given wins over the variable."""
    from typer.testing import CliRunner

    from baseline_cloudbaking.server.cli import CommandOptions, app, load_settings
    from baseline_cloudbaking.server.settings import OPTION_FORMS, env_name

    help_text = " ".join(CliRunner(env={"COLUMNS": "400"}).invoke(app, ["--help"]).output.split())
    for name, info in Settings.model_fields.items():
        option = "--" + OPTION_FORMS.get(name, {}).get("option", name).replace("_", "-")
        assert f"{option} " in help_text and info.description in help_text, name
        if not OPTION_FORMS.get(name, {}).get("required"):
            assert env_name(name) in help_text, name
    assert "(default: 256; env CLOUDBAKING_MAX_SPP) [1 to 4096]" in help_text
    assert "in MiB (default: 4096.0; env CLOUDBAKING_BUDGET_BYTES in bytes)" in help_text
    monkeypatch.setenv("CLOUDBAKING_MAX_SPP", "8")
    monkeypatch.setenv("CLOUDBAKING_MISS_QUEUE", "3")
    settings = load_settings(CommandOptions(store="s", max_spp=16, budget_mb=0.5))
    assert (settings.max_spp, settings.miss_queue, settings.budget_bytes) == (16, 3, 1 << 19)


@pytest.mark.parametrize(
    "argv", [["cloudbaking-server", "--port", "0"], ["cloudbaking-prebake", "lung_plane"]], ids=lambda a: a[0]
)
def test_an_empty_store_is_refused_and_writes_nothing(tmp_path: Path, argv: list[str]) -> None:
    """``--store ""`` would be the working folder. Each console script runs installed, as its own process (the
    other command-line errors of the cloud-baking scripts run in-process)."""
    check_user_error(run_script([*argv, "--store", ""], cwd=tmp_path), "--store is empty")


def test_a_store_whose_index_cannot_be_written_is_one_line_before_serving(server_run, tmp_path: Path) -> None:
    store = tmp_path / "s"
    GITree(store).close()
    index = store / "index.sqlite"
    if subprocess.run(["chattr", "+i", str(index)], capture_output=True).returncode != 0:
        pytest.skip("making the index read-only needs chattr +i: root on a file system with immutable files")
    try:
        result = server_run({})
    finally:
        subprocess.run(["chattr", "-i", str(index)], check=True)
    assert_error_line(result, "index.sqlite", "read-only")
    assert result.stdout == ""  # refused before it said it listens


@pytest.fixture(scope="module")
def app_client(tmp_path_factory: pytest.TempPathFactory, scenes_dir: Path):
    settings = Settings(
        store=tmp_path_factory.mktemp("hardening") / "store", scenes_dir=scenes_dir, resolutions=(32,), max_spp=1
    )
    with TestClient(create_app(settings)) as client:
        yield client


def post(client: TestClient, body: dict | str) -> httpx.Response:
    content = body if isinstance(body, str) else json.dumps(body)
    return client.post("/v1/gimap", content=content, headers={"content-type": "application/json"})


def cheap(**fields) -> dict:
    return gimap_body(resolution=32, spp=1) | fields


COERCED = [
    ("spp as a string", cheap(spp="1"), ["body", "spp"]),
    ("spp as a float", cheap(spp=1.0), ["body", "spp"]),
    ("resolution true", cheap(resolution=True), ["body", "resolution"]),
    ("di as 1", cheap(di=1), ["body", "di"]),
    ("di as a string", cheap(di="true"), ["body", "di"]),
    (
        "fov as a string",
        cheap(camera={"eye": [1, 1, 1], "target": [0, 0.5, 0], "fov": "90"}),
        ["body", "camera", "fov"],
    ),
    ("eye as strings", cheap(camera={"eye": ["1", 1, 1], "target": [0, 0.5, 0]}), ["body", "camera", "eye", "0"]),
    ("light true", cheap(light=[True, 2.2, 0.3]), ["body", "light", "0"]),
]


@pytest.mark.parametrize("what,body,loc", COERCED, ids=[c[0] for c in COERCED])
def test_json_of_the_wrong_type_is_422_naming_the_field(app_client: TestClient, what: str, body: dict, loc) -> None:
    response = post(app_client, body)
    assert response.status_code == 422, (what, response.text)
    assert loc in [[str(part) for part in d["loc"]] for d in response.json()["detail"]], response.text


def test_a_light_outside_the_scene_range_is_422_and_stores_nothing(app_client: TestClient) -> None:
    """ball_moving's light sweeps x in [-0.6, 0.6], y in [2.05, 2.35] at z = 0.3; a light cell (0.25) of margin."""
    before = app_client.get("/v1/stats").json()["entries"]
    for light in ([1e4, 2.2, 0.3], [0.0, -1e4, 0.3], [0.0, 2.2, 0.6], [0.9, 2.2, 0.3]):
        response = post(app_client, cheap(light=light))
        assert response.status_code == 422, (light, response.text)
        (detail,) = response.json()["detail"]
        assert detail["loc"] == ["body", "light"] and "light range" in detail["msg"], detail
    assert post(app_client, cheap(light=[0.8, 2.2, 0.3])).status_code == 200  # within the margin
    assert app_client.get("/v1/stats").json()["entries"] == before + 1
    scene = next(s for s in app_client.get("/v1/scenes").json()["scenes"] if s["name"] == "ball_moving")
    assert scene["light_min"] == pytest.approx([-0.6, 2.05, 0.3]) and scene["light_cell"] == 0.25


def test_the_openapi_document_states_what_the_server_applies(app_client: TestClient) -> None:
    """Its defaults are the ones a request that omits the field gets; its light box holds every scene's range."""
    doc = app_client.get("/openapi.json").json()["components"]["schemas"]["GIMapRequest"]["properties"]
    assert (doc["resolution"]["default"], doc["spp"]["default"]) == (32, 1)
    body = {k: v for k, v in gimap_body(eye=(1.3, 1.0, 1.7)).items() if k not in ("resolution", "spp")}
    response = post(app_client, body)
    assert response.status_code == 200, response.text
    assert app_client.get("/v1/stats").json()["by_scene_codec"]  # stored
    items = next(s for s in doc["light"]["anyOf"] if s.get("type") == "array")["prefixItems"]
    for scene in app_client.get("/v1/scenes").json()["scenes"]:
        for axis, item in enumerate(items):
            assert item["minimum"] <= scene["light_min"][axis] <= scene["light_max"][axis] <= item["maximum"]
    assert all(-100 < item["minimum"] and item["maximum"] < 100 for item in items)


def test_the_gi_tree_has_a_byte_budget_by_default(
    app_client: TestClient, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    assert app_client.get("/v1/stats").json()["budget_bytes"] == DEFAULT_BUDGET_BYTES == 4 << 30
    monkeypatch.setenv("CLOUDBAKING_BUDGET_BYTES", "12345")
    assert Settings(store=tmp_path).budget_bytes == 12345


def test_no_answer_names_an_absolute_path(tmp_path: Path) -> None:
    """Specs that fail (invalid, a mesh named by absolute path that is missing), a store holding a scene of
    another spec: the answers name files by their names only."""
    scenes = write_scenes(tmp_path / "scenes")
    (scenes / "broken.json").write_text(json.dumps({"name": "broken", "objects": []}))
    spec = json.loads((scenes / "ball_static.json").read_text())
    spec["objects"][0]["mesh"] = str(tmp_path / "elsewhere" / "gone.obj")
    (scenes / "ghost.json").write_text(json.dumps(spec | {"name": "ghost"}))
    store = tmp_path / "store"
    with GITree(store) as tree:
        tree.register_scene("ball_moving", "0" * 64, 0.25)  # baked from another spec
    settings = Settings(store=store, scenes_dir=scenes, resolutions=(32,), max_spp=1)
    with TestClient(create_app(settings)) as client:
        answers = [client.get("/v1/health"), client.get("/v1/scenes"), client.get("/openapi.json")]
        answers += [post(client, cheap(scene=name)) for name in ("broken", "ghost", "ball_moving")]
    assert [a.status_code for a in answers] == [200, 200, 200, 422, 422, 409]
    assert answers[0].json()["store"] == "store"
    assert {"broken", "ghost"} <= set(answers[1].json()["invalid"])
    for answer in answers:
        assert str(tmp_path) not in answer.text and "/tmp/" not in answer.text, answer.text
    assert "ghost.json" in answers[4].text and "gone.obj" in answers[4].text and "store" in answers[5].text


def test_redact_keeps_names_relative_to_the_public_folders() -> None:
    store, scenes = Path("/srv/gi/store"), Path("/srv/specs")
    text = (
        "cannot write the GI tree at /srv/gi/store (No space: /srv/gi/store/payloads/ab/x.gim); "
        f"{scenes}/a.json: mesh file {Path.home()}/meshes/b.obj: not found; see GET /v1/scenes"
    )
    assert redact(text, [store, scenes]) == (
        "cannot write the GI tree at store (No space: payloads/ab/x.gim); a.json: mesh file b.obj: not found; "
        "see GET /v1/scenes"
    )
