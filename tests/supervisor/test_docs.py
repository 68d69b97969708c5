"""The generated docs (supervisor/docs.py): the committed files are what the
schema and the parsers generate, a stale table is found, a schema that disagrees with
its loader is refused, and the generated template passes the real `check`."""

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from supervisor import docs
from supervisor.config.load import TOP_KEYS
from supervisor.config.schema import Key, Section

ROOT = Path(__file__).resolve().parents[2]


def _copy_docs(tmp_path: Path) -> Path:
    for rel in (docs.CONFIG_MD, docs.COMMANDS_MD, docs.TEMPLATE):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(ROOT / rel, tmp_path / rel)
    return tmp_path


def test_the_committed_docs_are_generated():
    diff = docs.differences(ROOT)
    assert not diff, (
        f"the generated docs are stale: run `{docs.COMMAND}` and commit the result\n"
        + "".join(diff[:60])
    )


def test_an_edited_default_in_a_generated_table_is_found(tmp_path):
    root = _copy_docs(tmp_path)
    md = root / docs.CONFIG_MD
    text = md.read_text()
    # The queue depth's default, as a hand edit of the reference would change it.
    edited = re.sub(r"(\| `depth` \| [^|]* \| )`1000`", r"\1`10`", text, count=1)
    assert edited != text
    md.write_text(edited)
    diff = "".join(docs.differences(root))
    assert "-| `depth` |" in diff and "`10`" in diff and "+| `depth` |" in diff


def test_a_doc_without_a_generated_block_is_refused(tmp_path):
    root = _copy_docs(tmp_path)
    md = root / docs.COMMANDS_MD
    md.write_text(
        re.sub(
            r"<!-- BEGIN GENERATED command:check .*?END GENERATED -->",
            "",
            md.read_text(),
            flags=re.S,
        )
    )
    with pytest.raises(docs.DocsError, match="command:check"):
        docs.differences(root)


def test_a_schema_section_that_lacks_a_key_of_its_loader_is_refused():
    ros = Section(
        "ros",
        "supervisor.config.ros:ROS_KEYS",
        (
            Key(
                "node_name",
                "name",
                "`{}`",
                "the node",
                "supervisor.config.model:RosConfig.node_name",
            ),
        ),
    )
    with pytest.raises(docs.DocsError, match=r"lacks: \[.*'heartbeat_ms'"):
        docs.config_table(ros)


def test_defaults_come_from_the_loaders():
    tables = docs.config_blocks()
    assert "| `depth` | whole number >= 1 | `1000` |" in tables["config:variables"]
    assert "| `max_resets` | whole number >= 1 | `1` |" in tables["config:control"]


def test_the_template_has_every_section_and_passes_check(tmp_path):
    text = docs.template_yaml()
    for key in sorted(TOP_KEYS):
        assert re.search(rf"^#?{key}:", text, re.M), f"template.yaml lacks {key}"
    # The depth default is said where the template sets another depth.
    assert "(default 1000)" in text
    path = tmp_path / "template.yaml"
    path.write_text(text)
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("SAFETY_SUPERVISOR_DEBUG", "STATE_DIRECTORY")
    }
    run = subprocess.run(
        [sys.executable, "-m", "supervisor", "check", str(path)],
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
    )
    assert run.returncode == 0, run.stdout + run.stderr
    assert "3 requirements ok" in run.stdout


def test_check_mode_exits_1_and_names_the_command_on_a_stale_file(tmp_path, monkeypatch, capsys):
    root = _copy_docs(tmp_path)
    (root / docs.TEMPLATE).write_text("component: Robot\n")
    monkeypatch.setattr(docs, "ROOT", root)
    assert docs.main(["--check"]) == 1
    assert docs.COMMAND in capsys.readouterr().err


def test_the_options_described_by_hand_are_the_parsers():
    """commands.md's hand-written option tables (the longer explanations beside the
    generated tables) name only options the command has."""
    from supervisor.cli import build_parser

    parsers = docs._subparsers(build_parser())
    unknown = []
    section, header = None, ""
    for line in (ROOT / docs.COMMANDS_MD).read_text().splitlines():
        if m := re.match(r"^## (\S+)$", line):
            section = m.group(1)
        elif m := re.match(r"^## (\S+) (\S+)$", line):  # a command's command: fleet replay
            section = f"{m.group(1)} {m.group(2)}"
            parsers[section] = docs._subparsers(parsers[m.group(1)])[m.group(2)]
        elif line.startswith("| ") and not line.startswith(("| `", "| ---")):
            header = line
        elif section in parsers and header.startswith("| option |") and line.startswith("| `-"):
            known = {o for a in parsers[section]._actions for o in a.option_strings}
            first = line.split("|")[1]
            unknown += [
                f"{section}: {o}"
                for o in re.findall(r"(?<![\w-])(--?[a-z][\w-]*)", first)
                if o not in known
            ]
    assert not unknown, unknown


def test_the_generated_docs_name_no_path_of_this_checkout():
    # The docs are generated in one checkout and compared in any other (CI clones
    # elsewhere): a default that is an installed file's path would differ there.
    root = str(Path(docs.__file__).resolve().parents[1])
    for path, text in docs.generated().items():
        assert root not in text, path
