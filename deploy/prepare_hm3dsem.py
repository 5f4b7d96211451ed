"""Lay out downloaded HM3DSem scenes the way jobs/mvpd.yaml reads them, under HM3D's numbered names.

HM3D ships each scene as a folder `<NNNNN>-<id>/` holding `<id>.glb` (in the `*-glb-v0.2` archive) and
`<id>.semantic.glb`, `<id>.semantic.txt` (in the `*-semantic-annots-v0.2` archive). The scene reader needs
the three files in one folder. It names a scene after a numbered folder `<NNNNN>-<id>` holding `<id>.*`
(else after the files), since MVPd's video names and the `hm3d` split mode need the numbered name
(`00808-y9hTuugGdiq`: 00000-00799 train, 00800-00899 the held-out pool). This links
(or copies, across file systems) each annotated scene's three files into
`<out>/<NNNNN>-<id>/<NNNNN>-<id>.{glb,semantic.glb,semantic.txt}`; nothing is rewritten.

    python deploy/prepare_hm3dsem.py /data/hm3d-downloads data/hm3dsem

Extract the four archives (train and val, glb and semantic-annots) anywhere under the first folder first.
A scene with annotations but no `<id>.glb` is reported and skipped (exit 1); rerunning is safe.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import sys
from pathlib import Path

NUMBERED = re.compile(r"^(\d{5})-(.+)$")
SUFFIXES = (".glb", ".semantic.glb", ".semantic.txt")


def place(source: Path, target: Path) -> None:
    """Hard-link `source` to `target` (a copy when they are on different file systems); keep a finished one."""
    if target.exists() and target.stat().st_size == source.stat().st_size:
        return
    partial = target.with_name(target.name + ".partial")
    partial.unlink(missing_ok=True)
    try:
        os.link(source, partial)
    except OSError:
        shutil.copyfile(source, partial)
    os.replace(partial, target)


def numbered_scenes(downloads: Path) -> dict[str, dict[str, Path]]:
    """`<NNNNN>-<id>` -> suffix -> file, for every folder holding `<id>.semantic.txt` (its .glb may be elsewhere)."""
    glbs = {path.parent.name: path for path in downloads.rglob("*.glb")
            if not path.name.endswith(".semantic.glb") and path.name == NUMBERED.sub(r"\2", path.parent.name) + ".glb"}
    scenes: dict[str, dict[str, Path]] = {}
    for text in sorted(downloads.rglob("*.semantic.txt")):
        folder = text.parent.name
        match = NUMBERED.match(folder)
        if match is None or text.name != f"{match.group(2)}.semantic.txt":
            continue
        files = {".semantic.txt": text, ".semantic.glb": text.with_name(f"{match.group(2)}.semantic.glb")}
        if folder in glbs:
            files[".glb"] = glbs[folder]
        scenes[folder] = files
    return scenes


def prepare(downloads: Path, out: Path) -> list[str]:
    """Place every complete scene under `out`; returns one line per scene that could not be placed."""
    problems = []
    for name, files in numbered_scenes(downloads).items():
        missing = [suffix for suffix in SUFFIXES if suffix not in files or not files[suffix].is_file()]
        if missing:
            problems.append(f"{name}: no {', '.join(missing)} file under {downloads}; extract its archive there")
            continue
        (out / name).mkdir(parents=True, exist_ok=True)
        for suffix in SUFFIXES:
            place(files[suffix], out / name / f"{name}{suffix}")
    return problems


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("downloads", type=Path, help="folder the HM3D archives were extracted under")
    parser.add_argument("out", type=Path, help="scenes.hm3dsem.root of the job (jobs/mvpd.yaml: data/hm3dsem)")
    args = parser.parse_args()
    found = len(numbered_scenes(args.downloads))
    if not found:
        sys.exit(f"{args.downloads}: no <NNNNN>-<id>/<id>.semantic.txt found; extract HM3D's semantic-annots archives there")
    problems = prepare(args.downloads, args.out)
    for line in problems:
        print(line, file=sys.stderr)
    print(f"{found - len(problems)} of {found} annotated scenes in {args.out}")
    sys.exit(1 if problems else 0)


if __name__ == "__main__":
    main()
