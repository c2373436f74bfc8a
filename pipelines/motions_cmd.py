"""``wrinkles motions``: list the procedural motion library."""

from __future__ import annotations

import argparse
import textwrap

HELP = "list the procedural motions with their descriptions and parameters"
DESCRIPTION = """\
List the procedural motion library. Each motion is a name usable as 'wrinkles body --motion
NAME', with parameters set by '--motion-param KEY=VALUE' (or its short form '--param'). Motions
can also come from AMASS .npz (SMPL, SMPL-H, SMPL-X layouts) and BVH files (CMU- and
Mixamo-style skeletons; '--rest' says what the file's rest pose stands for), given as paths.
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--params", action="store_true", help="also list each motion's parameters")


def run(args: argparse.Namespace) -> int:
    from sim.motions import list_motions, motion_parameters

    rows = list_motions()
    width = max(len(name) for name, _ in rows)
    for name, desc in rows:
        print(f"{name:<{width}}  {desc}")
        if args.params:
            for pname, default, doc in motion_parameters(name):
                line = f"--motion-param {pname}={default}  {doc}"
                print(textwrap.indent(textwrap.fill(line, 96, subsequent_indent="    "), " " * (width + 4)))
    return 0
