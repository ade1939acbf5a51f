"""Bad input gets one line naming the file and the fix, exit status 1, and nothing half-written."""

import shutil

import cv2
import numpy as np
import pytest
import trimesh

from rose_usd.case import load_case
from rose_usd.cli import main
from rose_usd.errors import InputError


def run_cli(capsys, *argv):
    try:
        code = main(list(argv))
    except SystemExit as exc:  # argparse's usage errors
        code = exc.code
    err = capsys.readouterr().err.strip()
    return code, err


def assert_one_line_error(code, err, *needles):
    assert code == 1, err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("error: ")
    for needle in needles:
        assert needle in lines[0], lines[0]


def test_missing_frame(capsys, case_copy, tmp_path):
    """A gap in the frame numbers names the folder and the missing frame."""
    (case_copy / "rgb" / "000010.png").unlink()
    code, err = run_cli(capsys, "reconstruct", str(case_copy), "-o", str(tmp_path / "out"))
    assert_one_line_error(code, err, "rgb", "frame 10 missing", "000009.png")
    assert not (tmp_path / "out").exists()


def test_unreadable_image(capsys, case_copy, tmp_path):
    """A truncated PNG is named."""
    (case_copy / "rgb" / "000005.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    code, err = run_cli(capsys, "reconstruct", str(case_copy), "-o", str(tmp_path / "out"))
    assert_one_line_error(code, err, "000005.png", "cannot read")


def test_a_frame_cut_short_is_refused_before_the_output_is_made(capsys, case_copy, tmp_path):
    """A PNG whose header reads but whose data stops (a copy that broke off) is named before
    any stage runs: no output folder is made."""
    frame = case_copy / "rgb" / "000010.png"
    frame.write_bytes(frame.read_bytes()[:5000])
    out = tmp_path / "out"
    code, err = run_cli(capsys, "run", "segment", str(case_copy), "-o", str(out))
    assert_one_line_error(code, err, "000010.png", "cannot read")
    assert not out.exists()


def test_a_complete_frame_is_not_decoded_to_be_checked(tmp_path):
    """The check reads a complete PNG's or JPEG's last bytes only; a JPEG with bytes after its
    end marker (a camera's trailer) still passes."""
    from rose_usd.io import images

    rgb = np.random.default_rng(0).integers(0, 255, (40, 60, 3), dtype=np.uint8)
    png, jpg = tmp_path / "a.png", tmp_path / "b.jpg"
    cv2.imwrite(str(png), rgb)
    cv2.imwrite(str(jpg), rgb)
    jpg.write_bytes(jpg.read_bytes() + b"trailer" * 10)
    before = set(images._DECODED)
    for path in (png, jpg):
        images.check_complete(path)
    assert images._DECODED == before
    png.write_bytes(png.read_bytes()[: png.stat().st_size // 2])
    with pytest.raises(InputError, match="cannot read"):
        images.check_complete(png)


def test_mismatched_frame_counts(capsys, case_copy, tmp_path):
    """Fewer depth maps than RGB frames is refused up front."""
    (case_copy / "depth" / "000047.png").unlink()
    code, err = run_cli(capsys, "reconstruct", str(case_copy), "-o", str(tmp_path / "out"))
    assert_one_line_error(code, err, "depth", "47 frames", "48")


def test_frames_of_different_sizes(capsys, case_copy, tmp_path):
    """A frame of another size is named."""
    img = cv2.imread(str(case_copy / "rgb" / "000003.png"))
    cv2.imwrite(str(case_copy / "rgb" / "000003.png"), cv2.resize(img, (160, 120)))
    code, err = run_cli(capsys, "reconstruct", str(case_copy), "-o", str(tmp_path / "out"))
    assert_one_line_error(code, err, "000003.png", "160x120")


def test_missing_K(case_copy):
    """Asking a case without cam_K.txt for its intrinsics says what to write."""
    (case_copy / "cam_K.txt").unlink()
    with pytest.raises(InputError, match="no cam_K.txt") as info:
        load_case(case_copy).K()
    assert "\n" not in str(info.value) and "fx 0 cx" in str(info.value)


def test_wrong_intrinsics(capsys, case_copy, tmp_path):
    """A K whose principal point is off the image fails at load, naming cam_K.txt."""
    np.savetxt(case_copy / "cam_K.txt", [[280.0, 0, 900.0], [0, 280.0, 120.0], [0, 0, 1]])
    code, err = run_cli(capsys, "reconstruct", str(case_copy), "-o", str(tmp_path / "out"))
    assert_one_line_error(code, err, "cam_K.txt", "outside the 320x240 image")


def test_depth_in_meters_is_detected(case_copy):
    """A uint16 depth PNG holding meters (values 0-3) is refused with the unit fix."""
    cv2.imwrite(str(case_copy / "depth" / "000000.png"), np.full((240, 320), 2, np.uint16))
    with pytest.raises(InputError, match="look like meters"):
        load_case(case_copy).depth_m(0)


def test_nan_and_zero_depth_become_invalid(case_copy):
    """NaN, inf, zero and negative depth in a .npy read as invalid (0), not as distances."""
    depth = np.full((240, 320), 1.5, np.float32)
    depth[0, :4] = [np.nan, np.inf, 0.0, -1.0]
    shutil.rmtree(case_copy / "depth")
    (case_copy / "depth").mkdir()
    for t in range(48):
        np.save(case_copy / "depth" / f"{t:06d}.npy", depth)
    d = load_case(case_copy).depth_m(0)
    assert list(d[0, :5]) == [0.0, 0.0, 0.0, 0.0, 1.5]


def test_depth_of_another_size(case_copy):
    """Depth that does not match the RGB size is named with both sizes."""
    cv2.imwrite(str(case_copy / "depth" / "000002.png"), np.full((120, 160), 1000, np.uint16))
    with pytest.raises(InputError, match="depth is 160x120, RGB is 320x240"):
        load_case(case_copy).depth_m(2)


def test_corrupt_video(capsys, tmp_path):
    """A video that cannot be decoded is named, with the fix."""
    case = tmp_path / "vid"
    case.mkdir()
    (case / "video.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42 this is not a video")
    code, err = run_cli(capsys, "reconstruct", str(case), "-o", str(tmp_path / "out"))
    assert_one_line_error(code, err, "video.mp4", "cannot decode")


def test_rose_toml_typo(capsys, case_copy, tmp_path):
    """A misspelled key in rose.toml is refused, the key it is likely a typo of named and the
    allowed keys listed."""
    text = (case_copy / "rose.toml").read_text().replace("category", "categroy")
    (case_copy / "rose.toml").write_text(text)
    code, err = run_cli(capsys, "reconstruct", str(case_copy), "-o", str(tmp_path / "out"))
    assert_one_line_error(code, err, "rose.toml", "categroy", "did you mean 'category'?")
    (case_copy / "rose.toml").write_text(text.replace("fps = 30", "fsp = 30"))
    code, err = run_cli(capsys, "reconstruct", str(case_copy), "-o", str(tmp_path / "out"))
    assert_one_line_error(code, err, "rose.toml", "did you mean 'fps'?")


def test_unknown_stage_and_backend(capsys, sample_case, tmp_path):
    """Unknown stage and backend names list the valid ones, a near miss the one meant."""
    code, err = run_cli(capsys, "run", "segmnt", str(sample_case), "-o", str(tmp_path / "o"))
    assert_one_line_error(code, err, "unknown stage", "segment")
    code, err = run_cli(
        capsys, "reconstruct", str(sample_case), "-o", str(tmp_path / "o"), "--backend", "capture=colmap"
    )
    assert_one_line_error(code, err, "no backend 'colmap'", "auto, rgbd, megasam, sfm, oracle")
    assert "Config" not in err  # a Python class means nothing on the command line
    case = tmp_path / "case"
    shutil.copytree(sample_case, case)
    (case / "rose.toml").write_text((case / "rose.toml").read_text() + '\n[backends]\nsegment = "sam3"\n')
    code, err = run_cli(capsys, "run", "capture", str(case), "-o", str(tmp_path / "o2"))
    assert_one_line_error(code, err, "rose.toml", "no backend 'sam3'", "did you mean sam2?", "auto, classical, sam2")
    assert "Config" not in err  # nor to someone editing rose.toml
    code, err = run_cli(capsys, "run", "segment", str(case), "-o", str(tmp_path / "o3"), "--backend", "segment=sam")
    assert_one_line_error(code, err, "--backend", "no backend 'sam'", "did you mean sam2?")


def test_an_output_folder_of_another_case_or_the_case_folder_is_refused(capsys, case_copy, out_copy):
    """Running a case into a folder that holds another case's stages would remove them as stale:
    refused with one line, nothing touched; so is the case folder itself as the output. (A copy
    of the case, unchanged, may use the folder its original's stages are in.)"""
    toml = case_copy / "rose.toml"
    toml.write_text(toml.read_text().replace('category = "box"', 'category = "box"\nsize_m = 0.1'))  # other inputs
    before = sorted((p.relative_to(out_copy), p.stat().st_mtime_ns) for p in out_copy.rglob("*"))
    code, err = run_cli(capsys, "reconstruct", str(case_copy), "-o", str(out_copy), "--backend", "all=oracle")
    assert_one_line_error(code, err, str(out_copy), "another case", "another folder")
    assert sorted((p.relative_to(out_copy), p.stat().st_mtime_ns) for p in out_copy.rglob("*")) == before
    listed = sorted(case_copy.rglob("*"))
    code, err = run_cli(capsys, "run", "capture", str(case_copy), "-o", str(case_copy), "--backend", "all=oracle")
    assert_one_line_error(code, err, "case folder itself", "-o out/case")
    assert sorted(case_copy.rglob("*")) == listed
    inside = case_copy / "gt" / "out"
    code, err = run_cli(capsys, "run", "capture", str(case_copy), "-o", str(inside), "--backend", "all=oracle")
    assert_one_line_error(code, err, "inside the case's gt/", str(case_copy / "out"))
    assert sorted(case_copy.rglob("*")) == listed


def test_an_output_folder_in_a_read_only_folder_is_refused_even_for_root(capsys, sample_case, tmp_path):
    """A new user ran `-o /work/shared/out_nu5` as root: the dataset's folder, read-only by its
    mode bits, got 5 minutes of output. A folder with no write bit is refused as one line."""
    import os

    shelf = tmp_path / "dataset"
    shelf.mkdir()
    os.chmod(shelf, 0o555)
    try:
        code, err = run_cli(
            capsys, "run", "capture", str(sample_case), "-o", str(shelf / "out"), "--backend", "all=oracle"
        )
        assert_one_line_error(code, err, str(shelf / "out"), f"{shelf} is read-only", "-o out/push-box")
        assert list(shelf.iterdir()) == []
    finally:
        os.chmod(shelf, 0o755)


def test_object_never_visible_leaves_no_mix(capsys, case_copy, out_copy):
    """An object that never appears fails the segment stage and leaves no mix: the capture re-run
    before it (its ground truth changed) made the old masks stale, so they went with the layers
    after them in its commit (issue 25), and what is left agrees with itself."""
    from rose_usd.usd.stage import consistency_problems

    for mask in (case_copy / "gt" / "masks" / "Box").glob("*.png"):
        cv2.imwrite(str(mask), np.zeros((240, 320), np.uint8))
    code, err = run_cli(capsys, "reconstruct", str(case_copy), "-o", str(out_copy), "--backend", "all=oracle")
    assert_one_line_error(code, err, "never visible", "Box")
    assert not (out_copy / "layers" / "masks.usda").exists() and not (out_copy / "masks").exists()
    assert (out_copy / "layers" / "world.usda").is_file()
    assert consistency_problems(out_copy) == []
    assert not [p for p in out_copy.iterdir() if p.name.startswith(".")]


def test_a_layer_of_another_case_is_blamed_not_those_made_after_it(out_copy):
    """A new user copied another run's object layer into an output folder: validate said the
    trajectory was made from layers/object.usda "which is missing" although it was there."""
    import json

    from pxr import Sdf

    from rose_usd.usd.stage import consistency_problems

    layer = Sdf.Layer.FindOrOpen(str(out_copy / "layers" / "object.usda"))
    data = dict(layer.customLayerData)
    prov = json.loads(data["rose"])
    prov["inputs"]["case"] = "another"
    data["rose"] = json.dumps(prov, sort_keys=True)
    layer.customLayerData = data
    layer.Save()
    problems = consistency_problems(out_copy)
    assert problems[0] == "layers/object.usda was made from another case than layers/world.usda", problems
    assert "layers/trajectory.usda depends on layers/object.usda, which does not belong here (above)" in problems
    assert not [p for p in problems if "missing" in p], problems


def test_a_missing_layer_and_a_broken_usda_are_named_in_one_line(capsys, out_copy, tmp_path):
    """A new user's trial: with layers/scene.usda deleted, validate printed USD's own "Could not
    load sublayer" warning (stage.cpp, line 3315) before a line that named no layer; a usda with a
    syntax error was reported by USD's C++ function and source file, cut off. Now: the missing
    layer, and the file's own line and column."""
    (out_copy / "layers" / "scene.usda").unlink()
    for command in ("validate", "inspect"):
        code, err = run_cli(capsys, command, str(out_copy))
        assert_one_line_error(code, err, "layers/scene.usda is missing", "rose-usd reconstruct")
    bad = tmp_path / "bad.usda"
    bad.write_text('#usda 1.0\n(\n    upAxis = "Z"\n)\n\ndef Xform "World" {\n    double3 a = (1, 2\n}\n')
    code, err = run_cli(capsys, "inspect", str(bad))
    assert_one_line_error(code, err, f"{bad}:8:1: parse error", "</World.a>")
    assert "pxrInternal" not in err and ".cpp" not in err and ".h " not in err


def test_a_usdz_with_a_sublayer_opens(tmp_path):
    """The missing-layer check looks at an output folder's files only: a .usdz's sublayers are in
    the package (a reviewer's find: a valid .usdz was refused)."""
    from pxr import Sdf, UsdUtils

    from rose_usd.usd.stage import open_stage

    Sdf.Layer.CreateAnonymous().Export(str(tmp_path / "sub.usda"))
    root = Sdf.Layer.CreateNew(str(tmp_path / "root.usda"))
    root.subLayerPaths.append("./sub.usda")
    root.Save()
    assert UsdUtils.CreateNewUsdzPackage(str(tmp_path / "root.usda"), str(tmp_path / "pack.usdz"))
    (tmp_path / "sub.usda").unlink()
    assert open_stage(tmp_path / "pack.usdz") is not None


def test_no_ground_truth_for_oracle(capsys, case_copy, tmp_path):
    """Oracle backends on a case without gt/ say which backend to choose instead."""
    shutil.rmtree(case_copy / "gt")
    code, err = run_cli(capsys, "reconstruct", str(case_copy), "-o", str(tmp_path / "out"), "--backend", "all=oracle")
    assert_one_line_error(code, err, "gt/scene.json", "has none", "--backend capture=oracle")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    "box,message",
    [
        ("0:208,127,174,90", "has its corners swapped"),
        ("0:300,200,330,250", "runs past the 320x240 image's right edge by 10 px, bottom edge by 10 px"),
        # fractions of the image: a traceback from OpenCV's GrabCut in the capture stage
        ("0:0.7,0.2,0.88,0.4", "is 0.18 x 0.2 px, under 2 px a side (fractions of the image?)"),
    ],
)
def test_a_command_line_box_off_the_image_says_which_way(capsys, sample_case, tmp_path, box, message):
    """A hand-typed --prompt box with its corners swapped, running past an edge or given as
    fractions of the image, is told as such."""
    out = tmp_path / "out"
    code, err = run_cli(capsys, "run", "segment", str(sample_case), "-o", str(out), "--prompt", box)
    assert_one_line_error(code, err, "--prompt", message)
    assert not out.exists()


def test_a_prompt_that_starts_with_a_minus_is_told_how_to_write_it(capsys, sample_case, tmp_path):
    """argparse takes "-1:..." after --prompt for an option and says only "expected one argument"."""
    code, err = run_cli(capsys, "run", "segment", str(sample_case), "-o", str(tmp_path / "out"), "--prompt", "-1:2,2")
    assert_one_line_error(code, err, "--prompt: expected one argument", "is written --prompt=VALUE")
    code, err = run_cli(capsys, "run", "segment", str(sample_case), "-o", str(tmp_path / "out"), "--prompt")
    assert_one_line_error(code, err, "--prompt: expected one argument")
    assert "--prompt=VALUE" not in err and not (tmp_path / "out").exists()
    code, err = run_cli(capsys, "run", "segment", str(sample_case), "-o", str(tmp_path / "out"), "--prompt=-1:2,2")
    assert_one_line_error(code, err, "--prompt", "is not [Name=]frame:x0,y0,x1,y1")


def test_a_command_line_prompt_on_nothing_names_the_prompt(capsys, sample_case, tmp_path):
    """A --prompt box where nothing stands names --prompt, not rose.toml (the stage's own error,
    raised in its child process)."""
    out = tmp_path / "out"
    code, err = run_cli(capsys, "run", "segment", str(sample_case), "-o", str(out), "--prompt", "0:2,2,12,12")
    assert_one_line_error(code, err, "segment.prompts (--prompt)", "nothing stands on the support", "draw the box")
    assert not (out / "layers" / "masks.usda").exists()


def _video(path, frames: int = 5):
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30, (320, 240))
    for t in range(frames):
        writer.write(np.full((240, 320, 3), 40 * t, np.uint8))
    writer.release()


def test_a_video_inside_rgb_is_the_cases_frames(capsys, tmp_path):
    """Real clips come as rgb/<name>.mp4 (openreal2sim-marker-rgb, visp-cube-hand-rgb): one video
    and no images in rgb/ are the frames; two videos there are one line naming them."""
    case = tmp_path / "clip"
    (case / "rgb").mkdir(parents=True)
    _video(case / "rgb" / "demo_video.avi")
    loaded = load_case(case)
    assert loaded.video == case / "rgb" / "demo_video.avi" and loaded.n_frames == 5
    _video(case / "rgb" / "second.avi")
    with pytest.raises(InputError, match="two or more videos") as err:
        load_case(case)
    assert "demo_video.avi" in err.value.one_line() and "second.avi" in err.value.one_line()


def test_a_video_files_settings_are_the_toml_beside_it(capsys, tmp_path):
    """A video given as the case: one generic "Object" alone; <stem>.toml (or <name>.toml) beside
    it (rose.toml's format) names its objects, their categories and sizes, and is checked like
    rose.toml."""
    video = tmp_path / "cups.avi"
    _video(video)
    assert [o.name for o in load_case(video).config.objects] == ["Object"]
    # no depth and no prompt: the fix names the file that is read, cups.toml, not rose.toml
    code, err = run_cli(capsys, "reconstruct", str(video), "-o", str(tmp_path / "out"))
    assert_one_line_error(code, err, f"write {tmp_path / 'cups.toml'} with [[objects]]", "--prompt")
    assert "rose.toml" not in err and not (tmp_path / "out").exists()
    toml = tmp_path / "cups.toml"
    toml.write_text('[[objects]]\nname = "Cup"\ncategory = "cup"\nsize_m = 0.095\n')
    loaded = load_case(video)
    (cup,) = loaded.config.objects
    assert (cup.name, cup.category, cup.overrides["size_m"]) == ("Cup", "cup", 0.095)
    assert toml in loaded.input_files()
    toml.write_text('[[objects]]\nname = "Cup"\ncategory = "cupp"\n')
    code, err = run_cli(capsys, "reconstruct", str(video), "-o", str(tmp_path / "out"))
    assert_one_line_error(code, err, "cups.toml", "'cupp'", "did you mean 'cup'")
    # the video's whole name with .toml added is read too, but not beside a <stem>.toml
    (tmp_path / "cups.avi.toml").write_text('[[objects]]\nname = "Mug"\n')
    with pytest.raises(InputError, match="two settings files beside the video: cups.toml and cups.avi.toml"):
        load_case(video)
    toml.unlink()
    assert [o.name for o in load_case(video).config.objects] == ["Mug"]


def test_validate_names_the_layers_an_output_folder_lacks_and_takes_the_folder(
    capsys, sample_case, oracle_out, tmp_path
):
    """An output folder stopped after capture (Ctrl-C, or `run capture`) is valid USD; validate says
    which stages' layers it lacks, and says nothing of the kind for a complete one."""
    from conftest import oracle_options

    from rose_usd.pipeline import Pipeline

    out = tmp_path / "out"
    Pipeline(sample_case, out, oracle_options()).run("capture")
    assert main(["validate", str(out / "rose.usda"), "--no-newton"]) == 0
    text = capsys.readouterr().out
    assert "incomplete: no layer of segment, scene, object, trajectory" in text, text
    assert main(["validate", str(oracle_out / "rose.usda"), "--no-newton"]) == 0
    assert "incomplete" not in capsys.readouterr().out
    # the output folder itself stands for its rose.usda (validate, inspect and diff)
    assert main(["validate", str(out), "--no-newton"]) == 0
    assert "incomplete: no layer of segment" in capsys.readouterr().out
    assert main(["inspect", str(oracle_out)]) == 0
    by_folder = capsys.readouterr().out
    assert main(["inspect", str(oracle_out / "rose.usda")]) == 0
    assert capsys.readouterr().out == by_folder and "gate:" in by_folder
    assert main(["diff", str(oracle_out), str(oracle_out / "rose.usda")]) == 0
    capsys.readouterr()
    # one layer of an output folder: its stage (a layer alone has no metersPerUnit, upAxis, defaultPrim)
    assert main(["validate", str(out / "layers" / "world.usda"), "--no-newton"]) == 0
    text = capsys.readouterr().out
    assert text.startswith(f"validating {out / 'rose.usda'}") and "0 error(s)" in text, text
    # inspect does the same, saying so on stderr (stdout stays the dump)
    assert main(["inspect", str(oracle_out / "layers" / "scene.usda")]) == 0
    got = capsys.readouterr()
    assert got.out == by_folder and got.err.startswith(f"inspecting {oracle_out / 'rose.usda'}"), got.err


def test_stage_commands_refuse_what_they_cannot_read_in_one_line(capsys, oracle_out, tmp_path):
    """A new user's trial: `validate` on a folder without rose.usda talked of "a folder, not a stage
    file"; `diff --rtol -1` listed every value as different; a usage error printed argparse's usage
    and exited 2 (rose-usd's status for a bug). Each is one line and exit 1 now; `--normalized`
    alone is the normalized JSON (it was ignored without --json)."""
    import json

    empty = tmp_path / "empty"
    empty.mkdir()
    for command in ("validate", "inspect"):
        assert_one_line_error(*run_cli(capsys, command, str(empty)), "empty", "no rose.usda in this folder")
    for flag, value in (("--rtol", "-1"), ("--atol", "-1"), ("--rtol", "x")):
        with pytest.raises(SystemExit) as exc:
            main(["diff", str(oracle_out), str(oracle_out), flag, value])
        assert_one_line_error(exc.value.code, capsys.readouterr().err, flag, f"{value} is not a tolerance")
    with pytest.raises(SystemExit) as exc:
        main(["reconstruct", str(tmp_path)])
    assert_one_line_error(exc.value.code, capsys.readouterr().err, "-o/--output", "rose-usd reconstruct --help")
    assert main(["inspect", str(oracle_out), "--normalized"]) == 0
    assert main(["inspect", str(oracle_out), "--json", "--normalized"]) == 0
    alone, with_json = capsys.readouterr().out.split("\n}\n", 1)
    assert json.loads(alone + "}") == json.loads(with_json)


def test_a_truncated_video_is_one_line_with_no_decoder_noise(tmp_path):
    """FFmpeg's own complaints about a cut-off H.264/MPEG-4 file ("Invalid NAL unit size", "partial
    file") went to the terminal before rose's one-line error; now the error line is all there is,
    and the frames decoded before the refusal are not left in the cache."""
    import os
    import subprocess
    import sys

    path = tmp_path / "cut.mp4"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 30, (320, 240))
    rng = np.random.default_rng(0)
    for _ in range(30):
        writer.write(rng.integers(0, 255, (240, 320, 3), dtype=np.uint8))
    writer.release()
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    env = {k: v for k, v in os.environ.items() if k != "OPENCV_FFMPEG_LOGLEVEL"}
    env["ROSE_USD_CACHE"] = str(tmp_path / "cache")
    done = subprocess.run(
        [sys.executable, "-m", "rose_usd.cli", "reconstruct", str(path), "-o", str(tmp_path / "out")],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert done.returncode == 1 and len(lines) == 1 and lines[0].startswith("error: "), done.stderr
    assert not list((tmp_path / "cache").rglob("*.png"))  # a refused video's frames are not kept


def test_a_missing_mesh_names_rose_toml_and_the_mesh_beside_it(capsys, case_copy, tmp_path):
    """rose.toml's mesh = "mesh/Box.obj" where mesh/ holds Box_m.obj: one line naming rose.toml, the
    missing file and the one beside it."""
    (case_copy / "mesh").mkdir()
    (case_copy / "mesh" / "Box_m.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    toml = case_copy / "rose.toml"
    toml.write_text(toml.read_text().replace('category = "box"', 'category = "box"\nmesh = "mesh/Box.obj"', 1))
    code, err = run_cli(capsys, "run", "capture", str(case_copy), "-o", str(tmp_path / "out"))
    assert_one_line_error(code, err, "rose.toml", "mesh/Box.obj", "holds 'Box_m.obj'")
    # a file that is there but no mesh (a new user's trial: capture ran 35 s before the object
    # stage could not read it), refused before anything is written
    toml.write_text(toml.read_text().replace('mesh = "mesh/Box.obj"', 'mesh = "rose.toml"', 1))
    code, err = run_cli(capsys, "reconstruct", str(case_copy), "-o", str(tmp_path / "out"))
    assert_one_line_error(code, err, "rose.toml", "mesh = 'rose.toml' is not a mesh file", ".obj")
    assert not (tmp_path / "out").exists()


def test_a_mesh_folder_of_two_meshes_asks_which_one(capsys, case_copy, tmp_path):
    """mesh/ holding Cat_m.obj and Cat_mm.obj (deepac-cat-rgb's layout) and rose.toml naming none:
    a new user's run used neither and fitted a box 37 % too large; now one line asks which, before
    anything is written."""
    (case_copy / "mesh").mkdir()
    for name in ("Box_m.obj", "Box_mm.obj"):
        (case_copy / "mesh" / name).write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    code, err = run_cli(capsys, "reconstruct", str(case_copy), "-o", str(tmp_path / "out"))
    assert_one_line_error(code, err, "rose.toml", "mesh/ holds 2 meshes (Box_m.obj, Box_mm.obj)", 'mesh = "mesh/')
    assert not (tmp_path / "out").exists()
    # one mesh in perception/ is the one, whatever mesh/ holds
    (case_copy / "perception").mkdir()
    (case_copy / "perception" / "Box.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    from rose_usd.case.layout import load_case

    case = load_case(case_copy)
    assert case.mesh_file(case.config.objects[0]).name == "Box.obj"


def test_mesh_units_that_make_no_object_are_refused(capsys, case_copy, tmp_path):
    """A millimetre mesh declared in meters (a new user's trial: a 12.8 cm cat read as 127.6 m,
    2.3e8 kg, exit 0): one line naming rose.toml and the units that fit, nothing written."""
    (case_copy / "mesh").mkdir()
    box = trimesh.creation.box((127.6, 80.0, 60.0))
    box.export(case_copy / "mesh" / "Box_mm.obj")
    toml = case_copy / "rose.toml"
    toml.write_text(
        toml.read_text().replace('category = "box"', 'category = "box"\nmesh = "mesh/Box_mm.obj"\nmesh_units = "m"', 1)
    )
    out = tmp_path / "out"
    code, err = run_cli(capsys, "reconstruct", str(case_copy), "-o", str(out))
    assert_one_line_error(code, err, "rose.toml", "Box_mm.obj is 127.6 m across", "is it in 'mm' (0.128 m)?")
    assert not out.exists()


def test_a_link_to_nothing_in_the_case_folder_is_named(capsys, case_copy, tmp_path):
    """mesh -> a mistyped folder: one line naming the link and where it points, nothing written
    (the case would otherwise run without its mesh, on a guessed scale)."""
    (case_copy / "mesh").symlink_to(tmp_path / "meshh")
    out = tmp_path / "out"
    code, err = run_cli(capsys, "reconstruct", str(case_copy), "-o", str(out))
    assert_one_line_error(code, err, "mesh", "meshh", "does not exist")
    assert not out.exists()


def test_objects_half_prompted_fail_before_capture_writes(capsys, case_copy, tmp_path):
    """Some objects prompted and some not: one line naming rose.toml (or --prompt), before the
    capture stage writes anything."""
    toml = case_copy / "rose.toml"
    toml.write_text(toml.read_text() + '\n[[objects]]\nname = "Ball"\n')
    code, err = run_cli(capsys, "reconstruct", str(case_copy), "-o", str(tmp_path / "out"))
    assert_one_line_error(code, err, "rose.toml", "'Ball' not", "prompt every object, or none")
    assert not (tmp_path / "out").exists()
    toml.write_text('fps = 30\n[[objects]]\nname = "Box"\n[[objects]]\nname = "Ball"\n')
    code, err = run_cli(
        capsys, "reconstruct", str(case_copy), "-o", str(tmp_path / "out"), "--prompt", "Box=0:174,90,208,127"
    )
    assert_one_line_error(code, err, "--prompt", "'Ball' not")
    assert not (tmp_path / "out").exists()


def test_a_wrong_list_is_shown_as_written(tmp_path):
    """rose.toml's box = [1, 2, 3] is named with its value, as TOML (a new user's trial read only
    "prompt box = a list is not a list of 4 numbers")."""
    from rose_usd.case.config import load_case_config
    from rose_usd.errors import ConfigError

    (tmp_path / "rose.toml").write_text('[[objects]]\nname = "Cup"\nprompt = { frame = 0, box = [1, 2.5, "x"] }\n')
    with pytest.raises(ConfigError) as err:
        load_case_config(tmp_path, ("segment",))
    assert 'box = [1, 2.5, "x"] is not a list of 4 numbers' in err.value.one_line()


def test_a_second_run_into_one_output_folder_is_refused(capsys, case_copy, out_copy):
    """While one run writes an output folder, another run into it (a batch re-run while the killed
    batch's worker still ran) is refused with one line and touches nothing; the lock goes with the
    process that held it, even killed (SIGKILL), and the folder is usable again at once."""
    import subprocess
    import sys

    hold = "import sys, time\nfrom rose_usd.usd.stage import output_lock\n"
    hold += "with output_lock(sys.argv[1]):\n    print('held', flush=True)\n    time.sleep(120)\n"
    holder = subprocess.Popen([sys.executable, "-c", hold, str(out_copy)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        before = sorted((p.relative_to(out_copy), p.stat().st_mtime_ns) for p in out_copy.rglob("*"))
        code, err = run_cli(capsys, "run", "capture", str(case_copy), "-o", str(out_copy), "--backend", "all=oracle")
        assert_one_line_error(code, err, str(out_copy), "another rose-usd run is writing this output folder")
        assert sorted((p.relative_to(out_copy), p.stat().st_mtime_ns) for p in out_copy.rglob("*")) == before
    finally:
        holder.kill()
        holder.wait()
    code, err = run_cli(capsys, "run", "capture", str(case_copy), "-o", str(out_copy), "--backend", "all=oracle")
    assert code == 0, err
