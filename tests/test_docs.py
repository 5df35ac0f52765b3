"""The manual (docs/, mkdocs.yml) and the README cannot drift from the product.

- the site builds with ``mkdocs build --strict`` (broken links, anchors, pages not in the nav);
- the generated reference pages equal what the code generates now, and a setting added to a
  service's model without regenerating them is caught;
- every setting has a description (the settings page shows it);
- every message quoted in the troubleshooting page is still in the code;
- every TOML example is a valid deployment file;
- every ``bash`` block of the getting-started, hardware and deployment pages runs (``sh``
  blocks need hardware, another machine or a long time), in a scratch folder with a free port
  in place of 7447 and each ``shepherd run`` cut to a few seconds.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from pydantic import BaseModel, Field

from services.runtime.config import ConfigError, parse_deployment
from services.tools import docs
from services.vertex_extractor.colour import ColourModel
from services.vertex_extractor.learn import write_colour_file
from tests.conftest import free_port

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
#: the pages whose bash blocks are run, in order, as one script each
RUNNABLE_PAGES = ["getting-started.md", "hardware/ir.md", "hardware/marker.md",
                  "hardware/camera.md", "hardware/ink.md", "deployments/robot-laptop.md",
                  "deployments/secure.md"]
#: verbs that talk to the bus: they get the test's endpoint unless the block gives one
BUS_VERBS = ("echo", "record", "replay", "sim snapshot", "ir send", "ir backend",
             "mission goto", "mission stop")
FOREGROUND_RUN_S, BACKGROUND_RUN_S = 6, 12
#: what each page's commands must print: the product did what the page says
EXPECTED = {
    "getting-started.md": ["humanoid/pose: seq=", "wrote run.mcap", "replayed ",
                           "wrote frame.png"],
    "hardware/ir.md": ["IR (dry run): walk_forward 0x86"],
    "hardware/marker.md": ["wrote marker.pdf", "wrote marker.png"],
    "hardware/camera.md": ["wrote grid.pdf"],
    "hardware/ink.md": ["wrote shot1.png", "wrote ink.toml"],
    "deployments/robot-laptop.md": ["running sim, vertex_extractor",
                                    "running mission_controller"],
    "deployments/secure.md": ["router.json5", "robot.json5", "laptop.json5"],
}


def fenced_blocks(text: str) -> list[tuple[str, str]]:
    """(language, code) of every fenced block of a Markdown page, in order."""
    blocks: list[tuple[str, str]] = []
    body: list[str] = []
    lang, fence, indent = "", "", 0
    for line in text.splitlines():
        stripped = line.strip()
        if not fence and stripped.startswith("```"):
            fence, lang, body = "```", stripped[3:].split(" ")[0].strip(), []
            indent = len(line) - len(line.lstrip())
        elif fence and stripped.startswith(fence):
            blocks.append((lang, "\n".join(body)))
            fence = ""
        elif fence:
            body.append(line[indent:])
    return blocks


def localise(script: str, port: int) -> str:
    """The script with the test's port for 7447, the test's endpoint for bus commands that
    give none, and each ``shepherd run`` limited to a few seconds (longer in the background,
    so that a later ``kill`` finds it)."""
    ep = f"tcp/127.0.0.1:{port}"
    out = []
    for line in script.replace("7447", str(port)).splitlines():
        m = re.search(r"\bshepherd run\b", line)
        if m and "--duration" not in line:
            seconds = BACKGROUND_RUN_S if line.split("#")[0].rstrip().endswith("&") \
                else FOREGROUND_RUN_S
            extra = f" --duration {seconds}"
            if "--listen" not in line and "--connect" not in line:
                extra += f" --listen {ep}"
            line = line[:m.end()] + extra + line[m.end():]
        for verb in BUS_VERBS:
            m = re.search(rf"\bshepherd {verb}\b", line)
            if m and "--connect" not in line:
                line = line[:m.end()] + f" --connect {ep}" + line[m.end():]
        out.append(line)
    return "\n".join(out)


def scratch_folder(tmp_path: Path) -> Path:
    """A folder with a copy of deploy/ (links resolved), where the pages' commands run."""
    shutil.copytree(ROOT / "deploy", tmp_path / "deploy", symlinks=False,
                    ignore=shutil.ignore_patterns("build", "certs"))
    return tmp_path


def shepherd_on_path(tmp_path: Path) -> dict[str, str]:
    """An environment whose ``shepherd`` is this checkout's, run by this interpreter."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    shim = bin_dir / "shepherd"
    shim.write_text(f'#!/bin/sh\nexec "{sys.executable}" -m services.tools.cli "$@"\n')
    shim.chmod(0o755)
    env = dict(os.environ, PATH=f"{bin_dir}{os.pathsep}{os.environ['PATH']}",
               PYTHONPATH=str(ROOT), NO_MKDOCS_2_WARNING="1")
    return env


def test_the_site_builds_strictly(tmp_path: Path):
    res = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--quiet",
                          "-f", str(ROOT / "mkdocs.yml"), "-d", str(tmp_path / "site")],
                         capture_output=True, text=True, timeout=300,
                         env=dict(os.environ, NO_MKDOCS_2_WARNING="1"))
    assert res.returncode == 0, res.stdout + res.stderr
    assert (tmp_path / "site" / "hardware" / "ir" / "index.html").is_file()
    assert (tmp_path / "site" / "reference" / "settings" / "index.html").is_file()


def test_the_reference_pages_are_current():
    assert docs.stale() == [], "run `shepherd docs` to regenerate docs/reference"


def test_a_setting_missing_from_the_pages_is_caught(monkeypatch):
    models = docs.settings_models()
    table, model = next((t, m) for t, m in models if t == "services.mission_controller")

    class Settings(model):  # type: ignore[misc, valid-type]
        brand_new_gain_m: float = Field(default=0.5, gt=0.0, description="a new setting")

    changed = [(t, Settings if t == table else m) for t, m in models]
    monkeypatch.setattr(docs, "settings_models", lambda: changed)
    page = docs.generate()["settings.md"]
    assert "| `brand_new_gain_m` | float | 0.5 | > 0.0 | m | a new setting |" in page
    assert docs.stale() == ["settings.md"]


def _all_fields(model: type[BaseModel], table: str) -> list[tuple[str, str | None]]:
    out = []
    for name, f in model.model_fields.items():
        if f.exclude:
            continue
        out.append((f"{table}.{name}", f.description))
        sub = docs.nested_model(f.annotation)
        if sub is not None:
            out += _all_fields(sub, f"{table}.{name}")
    return out


def test_every_setting_has_a_description():
    missing = [name for table, model in docs.settings_models()
               for name, description in _all_fields(model, table) if not description]
    assert missing == []


def test_every_command_and_option_has_help():
    import argparse

    from services.tools.cli import build_parser

    def walk(parser: argparse.ArgumentParser, path: str) -> list[str]:
        out = []
        for a in parser._actions:
            if isinstance(a, argparse._SubParsersAction):
                helps = {c.dest: c.help for c in a._choices_actions}
                for name, sub in a.choices.items():
                    if not helps.get(name):
                        out.append(f"{path} {name}")
                    out += walk(sub, f"{path} {name}")
            elif a.help is None:
                out.append(f"{path} {a.option_strings[0] if a.option_strings else a.dest}")
        return out

    assert walk(build_parser(), "shepherd") == []


def _source_text() -> str:
    return "\n".join(p.read_text(encoding="utf-8") for folder in ("services", "schemas")
                     for p in sorted((ROOT / folder).rglob("*.py")))


def test_every_troubleshooting_message_is_printed_by_the_code():
    page = (DOCS / "hardware" / "troubleshooting.md").read_text(encoding="utf-8")
    quoted = [m for m in re.findall(r"^\| `([^`]+)` \|", page, flags=re.MULTILINE)]
    assert len(quoted) >= 30
    source = _source_text()
    missing = []
    for message in quoted:
        fragments = [f for f in message.split("…") if len(f.strip()) >= 3]
        if not all(f in source for f in fragments):
            missing.append(message)
    assert missing == []


def test_a_message_the_code_does_not_print_is_caught():
    source = _source_text()
    assert "the marker is made of cheese" not in source


def test_every_toml_example_is_a_valid_deployment(tmp_path: Path):
    folder = scratch_folder(tmp_path)
    # the files the examples point at: a calibration and a learned ink
    shutil.copy(ROOT / "deploy" / "paper-camera.toml", folder / "camera.toml")
    write_colour_file(folder / "ink.toml", ColourModel(), "the default model")
    checked = 0
    for page in sorted(DOCS.rglob("*.md")):
        for lang, code in fenced_blocks(page.read_text(encoding="utf-8")):
            if lang != "toml":
                continue
            try:
                parse_deployment(tomllib.loads(code), folder / "example.toml")
            except ConfigError as err:
                pytest.fail(f"{page.relative_to(ROOT)}: {err}\n{code}")
            checked += 1
    assert checked >= 6


def test_the_readme_is_a_front_door():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 150
    pictures = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", text)
    assert pictures == ["docs/img/front.png"]
    assert (ROOT / pictures[0]).stat().st_size > 10_000
    assert "make test" in text and "make run" in text
    links = [t for t in re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", text) if "://" not in t]
    assert len(links) >= 10
    assert [t for t in links if not (ROOT / t).exists()] == []  # every page it points at
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    assert "make test" in ci  # the README's test command is the one CI runs


def test_the_picture_is_a_detected_frame_beside_the_floor_plan(tmp_path: Path):
    import cv2
    import numpy as np

    from services.tools.picture import make_picture
    run = tmp_path / "run"
    run.mkdir()
    cv2.imwrite(str(run / "floor_plan.png"), np.full((700, 700, 3), 255, np.uint8))
    written = make_picture(tmp_path / "img" / "front.png", run)
    assert [p.name for p in written] == ["front.png", "floor_plan.png"]  # no Fig. 9 here
    picture = cv2.imread(str(written[0]))
    assert picture is not None
    assert picture.shape == (480, 640 + 12 + 480, 3)  # the frame, a gap, the plan at 480
    caption = picture[:40, :640]
    assert caption.mean() < 80  # the dark band of the caption
    # the detected rhombus is drawn in green on the frame
    green = (picture[:, :640, 1] > 180) & (picture[:, :640, 0] < 100) & \
        (picture[:, :640, 2] < 100)
    assert green.sum() > 500


def test_localise_points_every_bus_command_at_the_test_port():
    script = localise("shepherd run &\nshepherd echo 'x/**' --count 3\n"
                      "shepherd router --listen tcp/127.0.0.1:7447 &\n"
                      "shepherd run deploy/a.toml --connect tcp/127.0.0.1:7447", 5555)
    assert script.splitlines() == [
        "shepherd run --duration 12 --listen tcp/127.0.0.1:5555 &",
        "shepherd echo --connect tcp/127.0.0.1:5555 'x/**' --count 3",
        "shepherd router --listen tcp/127.0.0.1:5555 &",
        "shepherd run --duration 6 deploy/a.toml --connect tcp/127.0.0.1:5555"]


@pytest.mark.slow
@pytest.mark.parametrize("page", RUNNABLE_PAGES)
def test_the_pages_commands_run(page: str, tmp_path: Path):
    blocks = [code for lang, code in fenced_blocks((DOCS / page).read_text(encoding="utf-8"))
              if lang == "bash"]
    assert blocks, f"{page} has no runnable (bash) block"
    script = localise("\n".join(blocks), free_port())
    folder = scratch_folder(tmp_path / "work")
    env = shepherd_on_path(tmp_path)
    log = tmp_path / "output.txt"
    with log.open("w") as out_file:  # a file, not a pipe: background jobs may outlive bash
        proc = subprocess.Popen(["bash", "-e", "-c", script], cwd=folder, env=env,
                                stdout=out_file, stderr=subprocess.STDOUT, text=True,
                                start_new_session=True)
        try:
            proc.wait(timeout=180)
        except subprocess.TimeoutExpired:
            pass
        finally:
            try:
                os.killpg(proc.pid, signal.SIGKILL)  # whatever the script left running
            except ProcessLookupError:
                pass
            proc.wait()
    out = log.read_text(errors="replace")
    report = f"{page}: exit {proc.returncode}\n--- script\n{script}\n--- output\n{out}"
    assert proc.returncode == 0, report
    assert "Traceback" not in out and "shepherd: " not in out, report  # no errors
    for expected in EXPECTED[page]:
        assert expected in out, f"{expected!r} not printed\n{report}"
