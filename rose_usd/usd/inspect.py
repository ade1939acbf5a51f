"""``rose-usd inspect``: what a person would look for in usdview, as a dict (and text), no display.

Layer stack with provenance, prims with types and applied schemas, physics values, mesh stats
with watertightness, cameras, time range, trajectories, masks and gate results.
:func:`normalize` turns a dump into the stable form kept under ``stages/`` and compared by
``rose-usd diff``.
"""

from __future__ import annotations

import math
import os
import posixpath
from pathlib import Path
from typing import Any

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdPhysics, UsdShade

from rose_usd.usd import paths, tokens
from rose_usd.usd import stage as stage_mod
from rose_usd.usd.geom import read_mesh


def _jsonable(value: Any) -> Any:
    if isinstance(value, (bool, int, str)) or value is None:
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else str(value)
    if isinstance(value, Sdf.AssetPath):
        return value.path
    if isinstance(value, (Gf.Quatd, Gf.Quatf, Gf.Quath)):
        return [value.GetReal(), *list(value.GetImaginary())]
    if isinstance(value, (Gf.Matrix4d, Gf.Matrix3d, Gf.Matrix4f, Gf.Matrix3f)):
        return np.array(value).tolist()
    if hasattr(value, "__len__") and not isinstance(value, (dict,)):
        return [_jsonable(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    return str(value)


def _summarize_samples(attr: Usd.Attribute) -> dict[str, Any]:
    times = attr.GetTimeSamples()
    values = [attr.Get(t) for t in times]
    out: dict[str, Any] = {"samples": len(times), "first_time": times[0], "last_time": times[-1]}
    if values and isinstance(values[0], (int, float)) and not isinstance(values[0], bool):
        arr = np.asarray(values, dtype=float)
        out.update(min=float(np.nanmin(arr)), mean=float(np.nanmean(arr)), max=float(np.nanmax(arr)))
    else:
        out.update(first=_jsonable(values[0]), last=_jsonable(values[-1]))
    return out


def _attributes(prim: Usd.Prim, prefix: str) -> dict[str, Any]:
    out = {}
    for attr in prim.GetAttributes():
        name = attr.GetName()
        if not name.startswith(prefix) or not attr.HasAuthoredValue():
            continue
        out[name] = _summarize_samples(attr) if attr.GetNumTimeSamples() > 0 else _jsonable(attr.Get())
    return out


def _mesh_info(prim: Usd.Prim) -> dict[str, Any]:
    import trimesh

    mesh = read_mesh(prim, world=False)
    tm = trimesh.Trimesh(vertices=mesh.vertices, faces=mesh.faces, process=False)
    watertight = bool(tm.is_watertight)
    info = {
        "points": int(len(mesh.vertices)),
        "triangles": int(len(mesh.faces)),
        "watertight": watertight,
        "winding_consistent": bool(tm.is_winding_consistent),
        "volume_m3": float(tm.volume) if watertight else None,
        "bounds_local_m": np.round(tm.bounds, 6).tolist(),
        "color": "texture"
        if mesh.texture is not None
        else ("vertex" if mesh.vertex_colors is not None else "constant"),
    }
    if mesh.texture is not None:
        info["texture"] = os.path.basename(str(mesh.texture))
    return info


def _physics_info(prim: Usd.Prim) -> dict[str, Any]:
    out: dict[str, Any] = {}
    if prim.HasAPI(UsdPhysics.RigidBodyAPI):
        out["rigid_body"] = True
    if prim.HasAPI(UsdPhysics.MassAPI):
        mass = UsdPhysics.MassAPI(prim)
        for key, attr in (
            ("mass_kg", mass.GetMassAttr()),
            ("center_of_mass_m", mass.GetCenterOfMassAttr()),
            ("diagonal_inertia", mass.GetDiagonalInertiaAttr()),
            ("principal_axes_wxyz", mass.GetPrincipalAxesAttr()),
        ):
            if attr.HasAuthoredValue():
                out[key] = _jsonable(attr.Get())
    if prim.HasAPI(UsdPhysics.CollisionAPI):
        out["collider"] = True
        if prim.HasAPI(UsdPhysics.MeshCollisionAPI):
            out["approximation"] = str(UsdPhysics.MeshCollisionAPI(prim).GetApproximationAttr().Get())
        material, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial("physics")
        if material and material.GetPrim().HasAPI(UsdPhysics.MaterialAPI):
            api = UsdPhysics.MaterialAPI(material.GetPrim())
            out["material"] = {
                "path": str(material.GetPath()),
                "static_friction": api.GetStaticFrictionAttr().Get(),
                "dynamic_friction": api.GetDynamicFrictionAttr().Get(),
                "restitution": api.GetRestitutionAttr().Get(),
            }
    if prim.IsA(UsdPhysics.Scene):
        scene = UsdPhysics.Scene(prim)
        out["gravity_direction"] = _jsonable(scene.GetGravityDirectionAttr().Get())
        out["gravity_magnitude"] = scene.GetGravityMagnitudeAttr().Get()
    return out


def _xform_info(prim: Usd.Prim) -> dict[str, Any] | None:
    xformable = UsdGeom.Xformable(prim)
    ops = xformable.GetOrderedXformOps()
    if not ops:
        return None
    out: dict[str, Any] = {"ops": [op.GetOpName() for op in ops]}
    pose = np.array(xformable.ComputeLocalToWorldTransform(Usd.TimeCode.Default())).T
    out["default_translation_m"] = pose[:3, 3].tolist()
    times = sorted({t for op in ops for t in op.GetAttr().GetTimeSamples()})
    if times:
        positions = np.array(
            [np.array(xformable.ComputeLocalToWorldTransform(Usd.TimeCode(t))).T[:3, 3] for t in times]
        )
        out["time_samples"] = len(times)
        out["first_translation_m"] = positions[0].tolist()
        out["last_translation_m"] = positions[-1].tolist()
        out["path_length_m"] = float(np.linalg.norm(np.diff(positions, axis=0), axis=1).sum())
    return out


def _metadata(stage: Usd.Stage) -> dict[str, Any]:
    """The stage's units, axes and time range."""
    return {
        "defaultPrim": stage.GetRootLayer().defaultPrim,
        "upAxis": UsdGeom.GetStageUpAxis(stage),
        "metersPerUnit": UsdGeom.GetStageMetersPerUnit(stage),
        "kilogramsPerUnit": UsdPhysics.GetStageKilogramsPerUnit(stage),
        "timeCodesPerSecond": stage.GetTimeCodesPerSecond(),
        "framesPerSecond": stage.GetFramesPerSecond(),
        "startTimeCode": stage.GetStartTimeCode(),
        "endTimeCode": stage.GetEndTimeCode(),
    }


def _layer_entry(root_dir: Path, sub: str) -> dict[str, Any]:
    """One sublayer: its spec count and the provenance its stage recorded."""
    layer = Sdf.Layer.FindOrOpen(str((root_dir / sub).resolve()) if not os.path.isabs(sub) else sub)
    entry: dict[str, Any] = {"name": Path(sub).stem, "file": sub}
    if layer is not None:
        prov = stage_mod.read_provenance(Path(layer.realPath)) or {}
        specs: list[Sdf.Path] = []
        layer.Traverse(Sdf.Path.absoluteRootPath, specs.append)
        entry.update(
            specs=len(specs),
            stage=prov.get("stage"),
            backend=stage_mod.shown_backend(prov, prov.get("backend")) if prov.get("backend") else None,
            wall_time_s=prov.get("wall_time_s"),
            config=prov.get("config"),
            results=prov.get("results"),
            warnings=prov.get("warnings", []),
            versions=prov.get("versions"),
        )
    return entry


def _camera_info(stage: Usd.Stage, prim: Usd.Prim) -> dict[str, Any]:
    """A camera's resolution, first intrinsics and path over the stage's frames."""
    from rose_usd.usd.camera import read_camera

    n = int(stage.GetEndTimeCode()) + 1
    track = read_camera(stage, prim.GetPath(), n)
    centers = track.world_from_cv[:, :3, 3]
    return {
        "resolution": [track.width, track.height],
        "K_frame0": np.round(track.K[0], 6).tolist(),
        "frames": n,
        "first_position_m": centers[0].tolist(),
        "path_length_m": float(np.linalg.norm(np.diff(centers, axis=0), axis=1).sum()),
    }


def _prim_entry(stage: Usd.Stage, prim: Usd.Prim) -> dict[str, Any]:
    """One prim: type, schemas, transform, geometry, physics, camera, light and rose: attributes."""
    p: dict[str, Any] = {"type": prim.GetTypeName()}
    schemas = list(prim.GetAppliedSchemas())
    if schemas:
        p["apiSchemas"] = sorted(schemas)
    if prim.IsA(UsdGeom.Imageable):
        purpose = UsdGeom.Imageable(prim).ComputePurpose()
        if purpose != UsdGeom.Tokens.default_:
            p["purpose"] = str(purpose)
    if prim.IsA(UsdGeom.Xformable) and not prim.IsA(UsdGeom.Camera):
        xf = _xform_info(prim)
        if xf:
            p["xform"] = xf
    if prim.IsA(UsdGeom.Mesh):
        p["mesh"] = _mesh_info(prim)
    phys = _physics_info(prim)
    if phys:
        p["physics"] = phys
    if prim.IsA(UsdGeom.Camera):
        p["camera"] = _camera_info(stage, prim)
    if prim.IsA(UsdLux.BoundableLightBase) or prim.IsA(UsdLux.NonboundableLightBase):
        light = UsdLux.LightAPI(prim)
        p["light"] = {"intensity": light.GetIntensityAttr().Get(), "color": _jsonable(light.GetColorAttr().Get())}
    rose = _attributes(prim, "rose:")
    if rose:
        p["rose"] = rose
    return p


def dump(path: str | os.PathLike) -> dict[str, Any]:
    """Everything worth seeing in a stage, as JSON-compatible data."""
    path = Path(path)
    stage = stage_mod.open_stage(path)
    out: dict[str, Any] = {
        "file": str(path),
        "metadata": _metadata(stage),
        "layers": [_layer_entry(path.parent, sub) for sub in stage.GetRootLayer().subLayerPaths],
        "prims": {},
    }
    if path.name == paths.ROOT_FILE:
        problems = stage_mod.consistency_problems(path.parent)
        if problems:  # absent when the layers agree (the normalized reference dumps stay as they are)
            out["problems"] = problems
    # defined or not: a stage of the later layers alone (`run segment` with the flow backend) holds
    # /World as an over, and the default traversal would skip everything under it
    for prim in stage.Traverse(Usd.TraverseInstanceProxies(Usd.PrimIsActive & Usd.PrimIsLoaded & ~Usd.PrimIsAbstract)):
        out["prims"][str(prim.GetPath())] = _prim_entry(stage, prim)
    gate = stage.GetPrimAtPath(paths.GATE)
    if gate:
        out["gate"] = _attributes(gate, "rose:gate:")
    robots = stage.GetPrimAtPath(paths.ROBOTS)
    if robots:
        collect = {str(r.GetName()): _attributes(r, "rose:collect:") for r in robots.GetChildren()}
        out["collect"] = {name: attrs for name, attrs in collect.items() if attrs}
    return out


# ----------------------------------------------------------------------------- normalize / text
_VOLATILE = {
    "wall_time_s",
    "versions",
    "file",
    "case",
    "case_parts",
    # the stages' own timings of their parts (two runs of one case differ by them alone)
    "frames_per_s",
    "sfm_seconds",
    "plan_s",
    "build_s",
    "build_timings",
    "rollout_wall_s",
    "rollouts_per_minute",
}


def normalize(data: Any, digits: int = 6) -> Any:
    """The stable form of a dump: volatile entries (timings, versions, absolute paths) dropped,
    floats rounded to ``digits`` significant digits, dict keys sorted."""
    if isinstance(data, dict):
        return {k: normalize(v, digits) for k, v in sorted(data.items()) if k not in _VOLATILE}
    if isinstance(data, list):
        return [normalize(v, digits) for v in data]
    if isinstance(data, float):
        if data == 0.0 or not math.isfinite(data):
            return data
        return float(f"{data:.{digits}g}")
    return data


def to_text(data: dict[str, Any]) -> str:
    """A human-readable summary of a dump."""
    lines = [f"stage {data['file']}"]
    md = data["metadata"]
    lines.append(
        f"  upAxis {md['upAxis']}, metersPerUnit {md['metersPerUnit']:g}, kilogramsPerUnit {md['kilogramsPerUnit']:g}, "
        f"{md['timeCodesPerSecond']:g} fps, time codes {md['startTimeCode']:g}..{md['endTimeCode']:g}, "
        f"defaultPrim {md['defaultPrim']}"
    )
    lines.append("layers (strongest first):")
    for layer in data["layers"]:
        wall = f"{layer['wall_time_s']:.1f} s" if layer.get("wall_time_s") is not None else "-"
        lines.append(f"  {layer['name']:<11} {layer.get('specs', 0):>5} specs  backend {layer.get('backend')}  {wall}")
        for warning in layer.get("warnings") or []:
            lines.append(f"      warning: {warning}")
    for problem in data.get("problems", []):
        lines.append(f"  LAYERS DISAGREE: {problem}")
    lines.append("prims:")
    for path, p in data["prims"].items():
        lines += _prim_lines(path, p)
    if "gate" in data:
        lines += _gate_lines(data["gate"])
    for robot, attrs in data.get("collect", {}).items():
        lines += _collect_lines(robot, attrs)
    return "\n".join(lines)


def _prim_lines(path: str, p: dict[str, Any]) -> list[str]:
    """One prim of a dump: its type, schemas and purpose, then its mesh, physics, trajectory,
    camera and light, each on a line."""
    lines = []
    depth = path.count("/") - 1
    tag = p["type"] or "(over)"
    extra = []
    if "apiSchemas" in p:
        extra.append("[" + ", ".join(p["apiSchemas"]) + "]")
    if "purpose" in p:
        extra.append(f"purpose={p['purpose']}")
    lines.append(f"  {'  ' * depth}{path.rsplit('/', 1)[-1]} <{tag}> {' '.join(extra)}".rstrip())
    pad = "  " * depth + "      "
    if "mesh" in p:
        m = p["mesh"]
        vol = f", volume {m['volume_m3'] * 1e6:.1f} cm^3" if m.get("volume_m3") else ""
        lines.append(
            f"{pad}mesh: {m['points']} points, {m['triangles']} triangles, "
            f"{'watertight' if m['watertight'] else 'NOT watertight'}{vol}, color {m['color']}"
        )
    if "physics" in p:
        ph = p["physics"]
        if "mass_kg" in ph:
            lines.append(
                f"{pad}mass {ph['mass_kg']:.4g} kg, "
                f"inertia {np.round(ph.get('diagonal_inertia', []), 8).tolist()} kg m^2, "
                f"CoM {np.round(ph.get('center_of_mass_m', []), 4).tolist()} m"
            )
        if "approximation" in ph:
            mat = ph.get("material")
            fr = f", friction {mat['dynamic_friction']:.3g}, restitution {mat['restitution']:.3g}" if mat else ""
            lines.append(f"{pad}collider: approximation {ph['approximation']}{fr}")
        if "gravity_magnitude" in ph:
            lines.append(f"{pad}gravity {ph['gravity_magnitude']:g} m/s^2 along {ph['gravity_direction']}")
    if "xform" in p and "time_samples" in p["xform"]:
        xf = p["xform"]
        lines.append(
            f"{pad}trajectory: {xf['time_samples']} samples, path {xf['path_length_m'] * 100:.1f} cm, "
            f"from {np.round(xf['first_translation_m'], 3).tolist()} "
            f"to {np.round(xf['last_translation_m'], 3).tolist()} m"
        )
    if "camera" in p:
        c = p["camera"]
        K = c["K_frame0"]
        lines.append(
            f"{pad}camera: {c['resolution'][0]}x{c['resolution'][1]}, "
            f"fx {K[0][0]:.2f} fy {K[1][1]:.2f} cx {K[0][2]:.2f} cy {K[1][2]:.2f}, "
            f"{c['frames']} frames, path {c['path_length_m'] * 100:.1f} cm"
        )
    if "light" in p:
        lines.append(
            f"{pad}light: intensity {p['light']['intensity']:.3g}, color {np.round(p['light']['color'], 3).tolist()}"
        )
    return lines


def _gate_lines(g: dict[str, Any]) -> list[str]:
    """The gate's results of a dump."""
    lines = []
    ssim = g.get(tokens.GATE_SSIM, {})
    lines.append("gate:")
    lines.append(
        f"  SSIM mean {g.get(tokens.GATE_SSIM_MEAN, float('nan')):.4f} "
        f"(min {ssim.get('min', float('nan')):.4f}) vs threshold "
        f"{g.get(tokens.GATE_SSIM_THRESHOLD, float('nan')):.2f}: "
        f"{'pass' if g.get(tokens.GATE_SSIM_PASSED) else 'FAIL'}"
    )
    objs = g.get(tokens.GATE_PHYSICS_OBJECTS, [])
    disp = g.get(tokens.GATE_PHYSICS_DISPLACEMENT, [])
    frames = g.get(tokens.GATE_PHYSICS_FRAMES, [])
    at = [f" from frame {t}" for t in frames] if len(frames) == len(objs) else [""] * len(objs)
    moves = ", ".join(
        [f"{o}{f} {d * 1000:.2f} mm" for o, f, d in zip(objs, at, disp)]
        + [f"{o} rests in no frame" for o in g.get(tokens.GATE_PHYSICS_NOT_RESTING, [])]
    )
    lines.append(
        f"  physics: rest check up to {g.get(tokens.GATE_PHYSICS_DURATION, 0):g} s: {moves or 'not run'}: "
        f"{('pass' if g.get(tokens.GATE_PHYSICS_PASSED) else 'FAIL') if objs else 'nothing checked'}"
    )
    names, ious = g.get(tokens.GATE_TRACK_OBJECTS, []), g.get(tokens.GATE_TRACK_IOU, [])
    track = ", ".join(f"{o} {v:.3f}" for o, v in zip(names, ious))
    verdict = "pass" if g.get(tokens.GATE_TRACK_PASSED) else "FAIL"
    lines.append(
        f"  track: re-render vs masks, mean IoU {track or 'not run'} vs threshold "
        f"{g.get(tokens.GATE_TRACK_THRESHOLD, float('nan')):.2f}: {verdict}"
    )
    lines.append(
        "  geometry: "
        f"{'pass' if g.get(tokens.GATE_GEOMETRY_PASSED) else 'FAIL: ' + g.get(tokens.GATE_GEOMETRY_REPORT, '')}"
    )
    lines.append(f"  overall: {'PASS' if g.get(tokens.GATE_PASSED) else 'FAIL'}")
    return lines


def _collect_lines(robot: str, c: dict[str, Any]) -> list[str]:
    """The collect stage's results of a dump, for one robot."""
    rollouts, successes = c.get(tokens.COLLECT_ROLLOUTS, 0), c.get(tokens.COLLECT_SUCCESSES, 0)
    if tokens.COLLECT_BASE_POSE in c:
        base = np.asarray(c[tokens.COLLECT_BASE_POSE], dtype=float)[3, :3]  # row-vector matrix
        where = f"base at {np.round(base, 3).tolist()} m ({c.get(tokens.COLLECT_BASE_SOURCE, 'reachability')})"
    else:
        where = "no base placed"
    status, moved = c.get(tokens.COLLECT_STATUS, "?"), c.get(tokens.COLLECT_OBJECT, "")
    what = f"moves {moved}, {where}" if moved else "moves nothing"  # stopped before choosing one (gate-failed)
    lines = [f"collect: {robot} {what}: status {status}"]
    if c.get(tokens.COLLECT_MESSAGE):
        lines.append(f"  {c[tokens.COLLECT_MESSAGE]}")
    rate = c.get(tokens.COLLECT_SUCCESS_RATE, 0.0)
    if rollouts:
        lines.append(f"  rollouts: {successes}/{rollouts} succeeded, success rate {100 * rate:.0f} %")
    best = c.get(tokens.COLLECT_BEST_ROLLOUT, -1)
    if rollouts and best >= 0:
        mean, final = c[tokens.COLLECT_MEAN_ERROR][best], c[tokens.COLLECT_FINAL_ERROR][best]
        drift, deg = c[tokens.COLLECT_DRIFT][best], c[tokens.COLLECT_FINAL_ROTATION_ERROR][best]
        lines.append(
            f"  best rollout {best} (time-sampled on the robot): path error {100 * float(mean):.1f} cm mean, "
            f"{100 * float(final):.1f} cm / {float(deg):.1f} deg final, {100 * float(drift):.1f} cm slip in the hand"
        )
    reasons = [r for r in c.get(tokens.COLLECT_ROLLOUT_REASON, []) if r]
    for reason in sorted(set(reasons)):
        lines.append(f"  failed x{reasons.count(reason)}: {reason}")
    if c.get(tokens.COLLECT_DATASET):
        # authored relative to layers/robot.usda: shown relative to the output folder
        path = str(c[tokens.COLLECT_DATASET])  # the dump holds an asset path's string
        shown = path if posixpath.isabs(path) else posixpath.normpath(posixpath.join("layers", path))
        both = paths.robomimic_beside(shown)
        lines.append(f"  datasets: {shown} (LeRobot v3) and {both} (robomimic), in the output folder")
    return lines
