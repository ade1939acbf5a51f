"""Object prompts (a box or a point on one frame): parsed from ``segment.prompts`` and checked
against the video, for every segment backend that takes them."""

from __future__ import annotations

from dataclasses import replace

from rose_usd.errors import ConfigError, InputError


def parse_prompts(prompts, specs) -> list:
    """The objects (``ObjectSpec``) with ``segment.prompts`` (ObjectPrompts) applied; a prompt
    without a name is the only object's."""
    out = {s.name: s for s in specs}
    for item in prompts:
        name = item.name or (specs[0].name if len(specs) == 1 else "")
        if name not in out:
            raise ConfigError(
                f"segment.prompts item {str(item)!r} names no object of rose.toml",
                hint=f"objects: {', '.join(out) or 'none'}; e.g. {next(iter(out), 'Box')}=0:120,80,200,170",
            )
        out[name] = replace(out[name], prompt=item.prompt)
    return list(out.values())


def prompts_source(prompts, case):
    """What an error about a prompt names: the command line's prompts (``segment.prompts``, from
    ``--prompt`` or ``--set``) when there are any, else the case's rose.toml."""
    return "segment.prompts (--prompt)" if prompts else case.settings_file


def check_prompts(specs, width: int, height: int, n: int, where) -> list:
    """The objects that have a prompt, after checking each lies in the video and that either every
    object or none has one."""
    prompted = [s for s in specs if s.prompt is not None]
    for s in prompted:
        if not 0 <= s.prompt.frame < n:
            raise InputError(
                f"prompt of {s.name!r} is on frame {s.prompt.frame}, the video has frames 0..{n - 1}",
                path=where,
                hint="prompt a frame of this video",
            )
        _check_prompt_inside(s, width, height, where)
    all_or_none(specs, where)
    return prompted


def all_or_none(specs, where) -> None:
    """InputError, naming the objects without one, unless every object or none has a prompt."""
    missing = [s.name for s in specs if s.prompt is None]
    if missing and len(missing) != len(specs):
        raise InputError(
            f"some objects have a prompt and some do not ({', '.join(repr(n) for n in missing)} not)",
            path=where,
            hint="prompt every object, or none",
        )


MIN_BOX_PX = 2
"""A prompt box narrower or lower than this [px] holds no object to segment."""


def _check_prompt_inside(spec, width: int, height: int, where) -> None:
    p = spec.prompt
    if p.box is not None:
        x0, y0, x1, y1 = p.box
        if not (x0 < x1 and y0 < y1):
            raise InputError(
                f"prompt box of {spec.name!r} {list(p.box)} has its corners swapped or no area",
                path=where,
                hint="give the top left corner first: x0, y0, x1, y1 with x0 < x1 and y0 < y1",
            )
        if x1 - x0 < MIN_BOX_PX or y1 - y0 < MIN_BOX_PX:
            fractions = max(p.box) <= 1.0
            raise InputError(
                f"prompt box of {spec.name!r} {list(p.box)} is {x1 - x0:g} x {y1 - y0:g} px,"
                f" under {MIN_BOX_PX} px a side" + (" (fractions of the image?)" if fractions else ""),
                path=where,
                hint=f"give the box in pixels of the {width}x{height} frame, around the whole object",
            )
        sides = (("left", -x0), ("top", -y0), ("right", x1 - width), ("bottom", y1 - height))
        past = [f"{side} edge by {d:g} px" for side, d in sides if d > 0]
        if past:
            raise InputError(
                f"prompt box of {spec.name!r} {list(p.box)} runs past the {width}x{height} image's {', '.join(past)}",
                path=where,
                hint=f"keep it inside the image: 0 <= x0 < x1 <= {width}, 0 <= y0 < y1 <= {height}",
            )
    elif p.point is not None:
        x, y = p.point
        if not (0 <= x < width and 0 <= y < height):
            raise InputError(
                f"prompt point of {spec.name!r} {list(p.point)} is outside the {width}x{height} image",
                path=where,
                hint="give the point in pixels of the prompt frame",
            )
