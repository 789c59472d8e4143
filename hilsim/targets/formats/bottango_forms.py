"""The three forms of a Bottango export, each reduced to the same command lines: the setup's,
and per animation its data, its loop data, its 8 config numbers and its name. What the
commands mean is :mod:`hilsim.targets.formats.bottango`; this module only finds them.

* Generated code (``GeneratedCodeAnimations.cpp``): C declarations ``SETUP_DATA_<k>``,
  ``ANIM_<i>_DATA<k>``, ``ANIM_<i>_LOOP[<k>]`` (string literals, several adjacent literals
  concatenated, C escapes decoded, one literal possibly on several lines; the ``<k>`` parts of
  one stream concatenated in order, a command may run across two of them, as the firmware's
  ``CodeCommandStreamDataSource`` reads them) and ``ANIM_<i>_CONFIG`` (``{8 integers}``).
  Comments and other code are skipped; ``// animation <i>, "<name>"`` gives the name.
* SD card (``anims/setup/data.txt``, ``anims/<i>/data.txt``, ``loop.txt``, ``config.txt``):
  one command or number per line; blank lines and lines starting with ``/`` are skipped (the
  firmware's config reader does so; here every file), ``\\r\\n`` ends a line too.
* JSON (``GET /AnimationCommands/`` of Bottango's REST API: "a JSON array of command
  strings"). Its exact envelope has not been seen, so it is read liberally (inferred):
  a flat array of strings is one stream (setup commands to the setup, the rest to
  animation 0); an array of arrays is blocks (a block of setup commands only is the setup,
  every other block one animation, in order); an object may name ``setup``, ``animations``
  and, per animation, ``commands``/``data``, ``loop``, ``config`` and ``name`` (keys in any
  case). A string holding several commands separated by newlines is split.
"""

from __future__ import annotations

import json
import re
from bisect import bisect_right
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from hilsim.targets.formats.common import FormatError, decode_text, read_bytes

#: registration and clean-up commands: a JSON block of only these is the setup
_SETUP_NAMES = "rSVPin rSVI2C rSTPin rSTDir rECC rECOnOff rECTrig rECColor rMTR rAud rCtrl upE"
SETUP_COMMANDS = frozenset(f"{_SETUP_NAMES} xE xUE xC xUC xCtrl xUCtrl".split(" "))


@dataclass(frozen=True)
class Line:
    """One command as the file gives it; ``path`` and ``where`` place it for a FormatError,
    ``label`` says which stream (``ANIM_0_DATA0 command 4``)."""

    text: str
    path: str
    where: str
    label: str = ""

    def error(self, message: str) -> FormatError:
        head = f"{self.label}: " if self.label else ""
        return FormatError(self.path, self.where, f"{head}{self.text[:60]!r}: {message}")


@dataclass
class RawAnimation:
    data: list[Line] = field(default_factory=list)
    loop: list[Line] = field(default_factory=list)
    config: tuple[int, ...] | None = None
    config_at: tuple[str, str] = ("", "")
    name: str = ""


@dataclass
class RawExport:
    path: str
    form: str
    setup: list[Line] = field(default_factory=list)
    animations: dict[int, RawAnimation] = field(default_factory=dict)


def read_text(path: Path) -> str:
    """The file as text; binary data or a file that cannot be read is one FormatError."""
    nul = "binary data (a NUL byte) where text is expected"
    return decode_text(read_bytes(path), path, nul, encoding="utf-8")


def _int(text: str, path: str, where: str, what: str) -> int:
    t = text.strip()
    if not re.fullmatch(r"[+-]?(\d+|0[xX][0-9a-fA-F]+)[uUlL]*", t):
        raise FormatError(path, where, f"{what}: {t[:30]!r} is not an integer")
    digits = t.rstrip("uUlL")
    value = int(digits, 16) if digits.lower().startswith("0x") else int(digits, 10)
    if not 0 <= value <= 65535:
        raise FormatError(path, where, f"{what}: {value} is outside 0-65535 (uint16)")
    return value


def split_lines(
    text: str, path: str, where_of: Callable[[int], str], label: str = ""
) -> list[Line]:
    """Commands separated by newlines (``\\r`` dropped, blank lines skipped); ``where_of(i)``
    places the command starting at offset i."""
    out: list[Line] = []
    pos = 0
    for chunk in text.split("\n"):
        cmd = chunk.strip("\r").strip()
        if cmd:
            k = len(out) + 1
            out.append(Line(cmd, path, where_of(pos), f"{label} command {k}" if label else ""))
        pos += len(chunk) + 1
    return out


# ----------------------------------------------------------------------------- generated code
_TOKEN = re.compile(
    r"""(?P<ws>\s+)|(?P<lc>//[^\n]*)|(?P<bc>/\*.*?\*/)|(?P<pp>\#[^\n]*)
    |(?P<str>"(?:[^"\\\n]|\\(?:.|\n))*")|(?P<chr>'(?:[^'\\\n]|\\.)*')
    |(?P<id>[A-Za-z_]\w*)|(?P<num>[0-9][\w.]*)|(?P<p>.)""",
    re.S | re.X,
)
_ESC = {"n": "\n", "r": "\r", "t": "\t", "\\": "\\", '"': '"', "'": "'", "?": "?",
        "a": "\a", "b": "\b", "f": "\f", "v": "\v", "\n": ""}  # fmt: skip
_ESC_RE = re.compile(r"\\(x[0-9a-fA-F]+|[0-7]{1,3}|.|\n)", re.S)
_DECL = re.compile(r"SETUP_DATA_?(\d+)|ANIM_(\d+)_(DATA|LOOP)(\d*)|ANIM_(\d+)_CONFIG")
_NAME = re.compile(r'//\s*animation\s+(\d+)\s*,\s*"(.*)"')


def _unescape(body: str, path: str, line: int) -> str:
    def one(m: re.Match[str]) -> str:
        e = m.group(1)
        if e in _ESC:
            return _ESC[e]
        if e[0] == "x" and len(e) > 1:
            return chr(int(e[1:], 16) & 0xFF)
        if e[0] in "01234567":
            return chr(int(e, 8) & 0xFF)
        raise FormatError(path, f"line {line}", f"unknown escape \\{e} in a string literal")

    return _ESC_RE.sub(one, body)


def _tokens(text: str, path: str) -> list[tuple[str, str, int]]:
    """(kind, text, line) of the C code's tokens; comments give ``name`` tokens only."""
    out: list[tuple[str, str, int]] = []
    pos, line, n = 0, 1, len(text)
    while pos < n:
        m = _TOKEN.match(text, pos)
        assert m is not None  # (?P<p>.) matches any character
        kind, tok = m.lastgroup or "p", m.group()
        if kind == "p" and tok in "\"'":
            raise FormatError(path, f"line {line}", f"unterminated {tok} literal")
        if kind == "p" and text.startswith("/*", pos):
            raise FormatError(path, f"line {line}", "unterminated /* comment")
        if kind == "lc" and (nm := _NAME.match(tok)):
            out.append(("name", nm.group(1) + "\0" + nm.group(2), line))
        elif kind in ("str", "id", "num", "p"):
            out.append((kind, tok, line))
        line += tok.count("\n")
        pos = m.end()
    return out


# long on purpose: one reader per form, the file's commands in turn
def read_code(path: Path) -> RawExport:  # noqa: C901, PLR0912, PLR0915
    """A ``GeneratedCodeAnimations.cpp``-style file."""
    text, spath = read_text(path), str(path)
    toks = _tokens(text, spath)
    # ("setup",), or (animation, "DATA" | "LOOP"): part -> (text, [(offset, line)], name)
    streams: dict[tuple[str] | tuple[int, str], dict[int, tuple[str, list[tuple[int, int]], str]]]
    streams = {}
    export = RawExport(spath, "code")
    names: dict[int, str] = {}
    i = 0
    while i < len(toks):
        kind, tok, line = toks[i]
        if kind == "name":
            idx, nm = tok.split("\0", 1)
            names[int(idx)] = nm
        m = _DECL.fullmatch(tok) if kind == "id" else None
        if not m or i + 1 >= len(toks) or toks[i + 1][1] != "[":
            i += 1
            continue
        j = i + 1
        while j < len(toks) and toks[j][1] != "=":
            if toks[j][1] == ";":
                raise FormatError(spath, f"line {line}", f"{tok} is declared without a value")
            j += 1
        end = j
        while end < len(toks) and toks[end][1] != ";":
            end += 1
        if end >= len(toks):
            raise FormatError(spath, f"line {line}", f"{tok}: no ';' ends the declaration")
        body = toks[j + 1 : end]
        if m.group(5) is not None:
            nums = [t for t in body if t[1] not in "{},"]
            if not body or body[0][1] != "{" or body[-1][1] != "}" or len(nums) != 8:
                raise FormatError(
                    spath,
                    f"line {line}",
                    f"{tok} must be {{8 integers}} "
                    "(playOnStart, loopOnStart, idleAnim, playOnPin, loop, playOnPinHigh, "
                    f"buttonLadderMin, buttonLadderMax); found {len(nums)} values",
                )
            anim = export.animations.setdefault(int(m.group(5)), RawAnimation())
            anim.config = tuple(_int(t, spath, f"line {ln}", tok) for _, t, ln in nums)
            anim.config_at = (spath, f"line {line}")
        else:
            if not body or any(k != "str" for k, _, _ in body):
                raise FormatError(spath, f"line {line}", f"{tok} must be string literals")
            s, at = "", []
            for _, lit, ln in body:
                at.append((len(s), ln))
                s += _unescape(lit[1:-1], spath, ln)
            key = ("setup",) if m.group(1) is not None else (int(m.group(2)), m.group(3))
            part = int(m.group(1) if m.group(1) is not None else (m.group(4) or 0))
            parts = streams.setdefault(key, {})
            if part in parts:
                raise FormatError(spath, f"line {line}", f"{tok} is declared twice")
            parts[part] = (s, at, tok)
        i = end + 1
    for key, parts in sorted(streams.items(), key=lambda kv: str(kv[0])):
        missing = sorted(set(range(max(parts) + 1)) - set(parts))
        if missing:
            name = parts[max(parts)][2]
            raise FormatError(spath, "", f"{name} is there but part {missing[0]} of it is not")
        text_all, offsets, lines = "", [], []
        for k in sorted(parts):
            s, at, tok = parts[k]
            for off, ln in at:
                offsets.append(len(text_all) + off)
                lines.append(ln)
            text_all += s

        def where_of(pos: int, offsets: list[int] = offsets, lines: list[int] = lines) -> str:
            return f"line {lines[max(bisect_right(offsets, pos) - 1, 0)]}"

        label = "SETUP_DATA" if len(key) == 1 else f"ANIM_{key[0]}_{key[1]}"  # 1: ("setup",)
        cmds = split_lines(text_all, spath, where_of, label)
        if len(key) == 1:
            export.setup = cmds
        else:
            anim = export.animations.setdefault(key[0], RawAnimation())
            if key[1] == "DATA":
                anim.data = cmds
            else:
                anim.loop = cmds
    for index, anim in export.animations.items():
        anim.name = names.get(index, "")
    if not export.setup and not export.animations:
        raise FormatError(
            spath,
            "",
            "no Bottango export data found (SETUP_DATA_<k>, ANIM_<i>_DATA<k>, "
            "ANIM_<i>_CONFIG declarations)",
        )
    return export


# ------------------------------------------------------------------------------------ SD card
def _sd_lines(path: Path, label: str = "") -> list[Line]:
    text, spath = read_text(path), str(path)
    out = []
    for n, raw in enumerate(text.split("\n"), 1):
        cmd = raw.strip("\r").strip()
        if cmd and not cmd.startswith("/"):
            out.append(Line(cmd, spath, f"line {n}", label))
    return out


def read_sd(root: Path) -> RawExport:
    """An SD-card export: ``root`` is the card (holding ``anims/``) or ``anims/`` itself."""
    anims = root / "anims" if (root / "anims").is_dir() else root
    if anims.name != "anims" or not anims.is_dir():
        raise FormatError(root, "", "not a Bottango SD-card export: no anims/ directory")
    export = RawExport(str(root), "sd")
    setup = anims / "setup" / "data.txt"
    if setup.is_file():
        export.setup = _sd_lines(setup)
    for sub in sorted(anims.iterdir()):
        if not (sub.is_dir() and sub.name.isdigit() and sub.name.isascii()):
            continue
        idx = int(sub.name)
        if idx in export.animations:
            raise FormatError(sub, "", f"animation {idx} is in two directories")
        data = sub / "data.txt"
        if not data.is_file():
            raise FormatError(sub, "", "no data.txt (the animation's commands)")
        anim = export.animations[idx] = RawAnimation(data=_sd_lines(data))
        if (sub / "loop.txt").is_file():
            anim.loop = _sd_lines(sub / "loop.txt")
        if (sub / "config.txt").is_file():
            lines = _sd_lines(sub / "config.txt")
            if len(lines) != 8:
                raise FormatError(
                    sub / "config.txt",
                    "",
                    f"{len(lines)} numbers; a config has 8 "
                    "(playOnStart, loopOnStart, idleAnim, playOnPin, loop, playOnPinHigh, "
                    "buttonLadderMin, buttonLadderMax), one per line",
                )
            anim.config = tuple(_int(ln.text, ln.path, ln.where, "config") for ln in lines)
            anim.config_at = (str(sub / "config.txt"), "")
    if not export.setup and not export.animations:
        raise FormatError(root, "", "empty SD-card export: no setup/data.txt and no <i>/data.txt")
    return export


# --------------------------------------------------------------------------------------- JSON
# long on purpose: one reader per form, the file's commands in turn
def read_json(path: Path) -> RawExport:  # noqa: C901
    """A JSON export (envelope inferred, read liberally: see the module docstring)."""
    text, spath = read_text(path), str(path)
    try:
        doc = json.loads(text)
    except RecursionError:
        raise FormatError(path, "", "JSON nested too deeply") from None
    except json.JSONDecodeError as exc:
        raise FormatError(path, f"line {exc.lineno}", f"not JSON: {exc.msg}") from None
    except ValueError as exc:  # e.g. an integer longer than Python's digit limit
        raise FormatError(path, "", f"not usable JSON: {exc}") from None
    export = RawExport(spath, "json")

    def commands(node: object, at: str) -> list[Line]:
        if isinstance(node, str):
            cmds = [c for c in (x.strip("\r").strip() for x in node.split("\n")) if c]
            many = len(cmds) > 1
            return [
                Line(c, spath, f"item {at or '(top)'}", f"command {k}" if many else "")
                for k, c in enumerate(cmds, 1)
            ]
        if isinstance(node, list) and all(isinstance(x, str) for x in node):
            return [ln for k, x in enumerate(node) for ln in commands(x, f"{at}[{k}]")]
        raise FormatError(path, f"item {at or '(top)'}", "expected command strings here")

    def keyed(obj: dict[object, object], *names: str) -> tuple[str, object] | None:
        for k, v in obj.items():
            if isinstance(k, str) and k.lower() in names:
                return k, v
        return None

    def animation(node: object, at: str) -> None:
        anim = export.animations[len(export.animations)] = RawAnimation()
        if not isinstance(node, dict):
            anim.data = commands(node, at)
            return
        for names, attr in ((("commands", "data"), "data"), (("loop",), "loop")):
            if kv := keyed(node, *names):
                setattr(anim, attr, commands(kv[1], f"{at}.{kv[0]}"))
        if kv := keyed(node, "name"):
            anim.name = str(kv[1])
        if kv := keyed(node, "config"):
            cfg = kv[1]
            where = f"item {at}.{kv[0]}"
            if not (isinstance(cfg, list) and len(cfg) == 8):
                raise FormatError(path, where, "a config is a list of 8 integers")
            anim.config = tuple(_int(str(v), spath, where, "config") for v in cfg)
            anim.config_at = (spath, where)

    if isinstance(doc, dict):
        if kv := keyed(doc, "setup", "setupcommands"):
            export.setup = commands(kv[1], f".{kv[0]}")
        if kv := keyed(doc, "animations", "anims"):
            if not isinstance(kv[1], list):
                raise FormatError(path, f"item .{kv[0]}", "animations must be an array")
            for k, node in enumerate(kv[1]):
                animation(node, f".{kv[0]}[{k}]")
    elif isinstance(doc, list) and all(isinstance(x, str) for x in doc):
        lines = commands(doc, "")
        export.setup = [ln for ln in lines if ln.text.split(",", 1)[0] in SETUP_COMMANDS]
        rest = [ln for ln in lines if ln.text.split(",", 1)[0] not in SETUP_COMMANDS]
        if rest:
            export.animations[0] = RawAnimation(data=rest)
    elif isinstance(doc, list):
        for k, node in enumerate(doc):
            block = commands(node, f"[{k}]") if not isinstance(node, dict) else None
            if (
                block is not None
                and not export.setup
                and not export.animations
                and all(ln.text.split(",", 1)[0] in SETUP_COMMANDS for ln in block)
            ):
                export.setup = block
            else:
                animation(node, f"[{k}]")
    else:
        raise FormatError(path, "", "expected a JSON array of command strings")
    if not export.setup and not export.animations:
        raise FormatError(path, "", "no Bottango commands in the JSON")
    return export
