"""Tiny datasets in each published thermal layout, generated in code (no download).

Every writer puts the same cameras (known OpenCV camera-to-world poses and intrinsics) into its
layout's own convention, so a test can check that a known 3D point reprojects to the same pixel
after parsing. The facts each writer mirrors are those of the datasets' own loaders:
- ThermalNeRF (Lin et al.): transforms.json, OpenGL axes, RGB + thermal frames flagged
  `is_thermal`, per-frame intrinsics and k1, k2, p1, p2, thermal frames `images_thermal/*.png`
  8-bit grey; evenly spaced 90/10 split.
- Thermal-NeRF (Ye et al.): `{train,test}/{intrinsics,pose,rgb}/`, one 4x4 text matrix per file
  (intrinsics; camera-to-world, OpenCV axes), 382x288 frames; split by folder.
- LLFF / MVTV: `poses_bounds.npy` [N, 17] (3x5 [R|t|hwf], axes down/right/back, + near/far).
- MSX (RGBT-Scenes): `rgb/{train,test}`, `thermal/{train,test}` iron-palette JPGs 640x480 named
  like the RGB frames, `sparse/0/*.bin`; test = every 8th image.
- ThermalMix (Ozer et al.): `thermal/*.jpg` 8-bit grey linear in degC between per-scene bounds,
  `colmap_sparse/0`; one held-out view.
- TI-NSD (Thermal3D-GS) / generic COLMAP: `images/` + `sparse/0/*.bin`, every 8th by name is test.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import List, Optional, Sequence, Tuple

import cv2
import numpy as np

from thermal_wild_ns.data.palettes import apply_palette

KNOWN_POINT = np.array([0.3, -0.2, 0.25])
"""A world point every fixture camera sees."""


def cameras(n: int = 10, radius: float = 4.0) -> List[np.ndarray]:
    """n OpenCV camera-to-world poses on an arc, looking at the origin (world z up)."""
    poses = []
    for i in range(n):
        angle = -0.8 + 1.6 * i / max(n - 1, 1)
        centre = np.array([radius * np.sin(angle), -radius * np.cos(angle), 1.0 + 0.1 * i])
        forward = -centre / np.linalg.norm(centre)
        right = np.cross(forward, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        down = np.cross(forward, right)
        c2w = np.eye(4)
        c2w[:3, :3] = np.stack([right, down, forward], axis=1)
        c2w[:3, 3] = centre
        poses.append(c2w)
    return poses


def project(c2w: np.ndarray, K: np.ndarray, point: np.ndarray = KNOWN_POINT) -> np.ndarray:
    """Pixel (COLMAP convention) of a world point in an OpenCV camera."""
    cam = np.linalg.inv(c2w) @ np.append(point, 1.0)
    return (K @ (cam[:3] / cam[2]))[:2]


def thermal_image(width: int, height: int, i: int, dtype=np.uint16) -> np.ndarray:
    """A smooth frame with some structure (so palettes and JPEG behave as on real data)."""
    v, u = np.mgrid[0:height, 0:width]
    base = 0.5 + 0.3 * np.sin(u / 17.0 + i) * np.cos(v / 13.0) + 0.1 * (u / width)
    if dtype == np.uint16:
        return (3500 + 400 * base).astype(np.uint16)
    return np.clip(base * 255, 0, 255).astype(np.uint8)


def _K(fx, fy, cx, cy) -> np.ndarray:
    return np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])


def opengl(c2w: np.ndarray) -> np.ndarray:
    return c2w @ np.diag([1.0, -1.0, -1.0, 1.0])


def write_thermalnerf(root: Path, n: int = 10) -> List[Tuple[np.ndarray, np.ndarray]]:
    """Returns (c2w OpenCV, K) of the thermal frames in order."""
    (root / "images_thermal").mkdir(parents=True)
    (root / "images_rgb").mkdir()
    frames, truth = [], []
    for i, c2w in enumerate(cameras(n)):
        rgb = np.zeros((60, 80, 3), np.uint8)
        cv2.imwrite(str(root / "images_rgb" / f"{i:04d}.png"), rgb)
        frames.append(
            {
                "file_path": f"images_rgb/{i:04d}.png",
                "is_thermal": False,
                "transform_matrix": opengl(c2w).tolist(),
                "fl_x": 70.0,
                "fl_y": 70.0,
                "cx": 40.0,
                "cy": 30.0,
                "w": 80,
                "h": 60,
                "k1": 0.0,
                "k2": 0.0,
                "p1": 0.0,
                "p2": 0.0,
            }
        )
        K = _K(52.0, 53.0, 33.0, 23.5)
        cv2.imwrite(str(root / "images_thermal" / f"{i:04d}.png"), thermal_image(64, 48, i, np.uint8))
        frames.append(
            {
                "file_path": f"images_thermal/{i:04d}.png",
                "is_thermal": True,
                "transform_matrix": opengl(c2w).tolist(),
                "fl_x": 52.0,
                "fl_y": 53.0,
                "cx": 33.0,
                "cy": 23.5,
                "w": 64,
                "h": 48,
                "k1": 0.0,
                "k2": 0.0,
                "p1": 0.0,
                "p2": 0.0,
            }
        )
        truth.append((c2w, K))
    (root / "transforms.json").write_text(json.dumps({"camera_model": "OPENCV", "frames": frames}))
    return truth


def write_nerfstudio(root: Path, n: int = 10) -> List[Tuple[np.ndarray, np.ndarray]]:
    """nerfstudio transforms.json of 16-bit thermal frames, global intrinsics (every 8th held out)."""
    (root / "images").mkdir(parents=True)
    K = _K(55.0, 56.0, 32.0, 24.0)
    frames, truth = [], []
    for i, c2w in enumerate(cameras(n)):
        cv2.imwrite(str(root / "images" / f"{i:04d}.png"), thermal_image(64, 48, i))
        frames.append({"file_path": f"images/{i:04d}.png", "transform_matrix": opengl(c2w).tolist()})
        truth.append((c2w, K))
    meta = {
        "camera_model": "OPENCV",
        "fl_x": 55.0,
        "fl_y": 56.0,
        "cx": 32.0,
        "cy": 24.0,
        "w": 64,
        "h": 48,
        "frames": frames,
    }
    (root / "transforms.json").write_text(json.dumps(meta))
    return truth


def write_ye(root: Path, n: int = 10) -> List[Tuple[np.ndarray, np.ndarray]]:
    """Sequence folder; frames with i % 5 == 4 are test. Returns (c2w, K) in name order."""
    K = _K(250.0, 251.0, 191.0, 144.0)
    truth = []
    for i, c2w in enumerate(cameras(n)):
        split = "test" if i % 5 == 4 else "train"
        for sub in ("intrinsics", "pose", "rgb"):
            (root / split / sub).mkdir(parents=True, exist_ok=True)
        K4 = np.eye(4)
        K4[:3, :3] = K
        np.savetxt(root / split / "intrinsics" / f"{i:05d}.txt", K4)
        np.savetxt(root / split / "pose" / f"{i:05d}.txt", c2w)
        cv2.imwrite(str(root / split / "rgb" / f"{i:05d}.png"), thermal_image(382, 288, i))
        truth.append((c2w, K))
    return truth


def write_llff(root: Path, n: int = 10, folder: str = "images") -> List[Tuple[np.ndarray, np.ndarray]]:
    """Poses recorded at 2x the stored resolution (as LLFF's images_2 are)."""
    (root / folder).mkdir(parents=True)
    rows, truth = [], []
    for i, c2w in enumerate(cameras(n)):
        right, down, forward = c2w[:3, 0], c2w[:3, 1], c2w[:3, 2]
        m = np.stack([down, right, -forward, c2w[:3, 3], [96.0, 128.0, 110.0]], axis=1)  # h, w, f at 2x
        rows.append(np.concatenate([m.reshape(-1), [1.0, 10.0]]))
        cv2.imwrite(str(root / folder / f"IMG_{i:04d}.png"), thermal_image(64, 48, i))
        truth.append((c2w, _K(55.0, 55.0, 32.0, 24.0)))
    np.save(root / "poses_bounds.npy", np.array(rows))
    return truth


def write_colmap_model(
    folder: Path,
    names: List[str],
    poses: List[np.ndarray],
    K: np.ndarray,
    size: Tuple[int, int],
    binary: bool = True,
    with_point: bool = True,
    extra_points: int = 0,
) -> None:
    """A COLMAP model of these posed images, with KNOWN_POINT as its first 3D point (or none) and
    `extra_points` more around it."""
    import pycolmap

    folder.mkdir(parents=True, exist_ok=True)
    rec = pycolmap.Reconstruction()
    camera = pycolmap.Camera(
        model="PINHOLE", width=size[0], height=size[1], params=[K[0, 0], K[1, 1], K[0, 2], K[1, 2]]
    )
    camera.camera_id = 1
    rec.add_camera_with_trivial_rig(camera)
    for i, (name, c2w) in enumerate(zip(names, poses)):
        w2c = np.linalg.inv(c2w)
        rec.add_image_with_trivial_frame(
            pycolmap.Image(name=name, camera_id=1, image_id=i + 1),
            pycolmap.Rigid3d(pycolmap.Rotation3d(w2c[:3, :3]), w2c[:3, 3]),
        )
    if with_point:
        rec.add_point3D(KNOWN_POINT, pycolmap.Track(), np.array([200, 200, 200], np.uint8))
        for offset in np.random.default_rng(0).normal(0.0, 0.2, (extra_points, 3)):
            rec.add_point3D(KNOWN_POINT + offset, pycolmap.Track(), np.array([100, 100, 100], np.uint8))
    rec.write_binary(str(folder)) if binary else rec.write_text(str(folder))


def write_msx(root: Path, n: int = 16) -> List[Tuple[np.ndarray, np.ndarray]]:
    """RGBT-Scenes as released: img_001.jpg ... in rgb/{train,test} and thermal/{train,test} (same
    names), the test views every 8th from the first (img_001, img_009, ...), sparse/0 on the RGB."""
    K = _K(500.0, 500.0, 320.0, 240.0)
    names = [f"img_{i + 1:03d}.jpg" for i in range(n)]
    for i, name in enumerate(names):
        split = "test" if i % 8 == 0 else "train"
        for sub in ("rgb", "thermal"):
            (root / sub / split).mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(root / "rgb" / split / name), np.zeros((480, 640, 3), np.uint8))
        iron = apply_palette(thermal_image(640, 480, i, np.uint8), "iron")
        cv2.imwrite(str(root / "thermal" / split / name), iron[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 95])
    poses = cameras(n)
    write_colmap_model(root / "sparse" / "0", names, poses, K, (640, 480))
    return [(c2w, K) for c2w in poses]


def write_thermalmix(
    root: Path, n: int = 24, fmt: str = "jpg", missing: Sequence[int] = ()
) -> List[Tuple[np.ndarray, np.ndarray]]:
    """The authors' structure (`mert-o/thermalnerfs`): `rgb/IMG_xxx.JPG`, unwarped `thermal/*.jpg`
    (deliberately different pixels: they must never be read), the frames the poses belong to in
    `warped_thermal/` (`.jpg` 8-bit or `.npy` degC), `colmap_sparse/0`. Images in `missing` have no
    warped frame. `root` should be named after a scene (e.g. .../lion) for its published bounds."""
    K = _K(90.0, 90.0, 40.0, 30.0)
    for folder in ("thermal", "rgb", "warped_thermal"):
        (root / folder).mkdir(parents=True, exist_ok=True)
    names = [f"IMG_{i:03d}.JPG" for i in range(n)]
    for i in range(n):
        frame = thermal_image(80, 60, i, np.uint8)
        cv2.imwrite(str(root / "thermal" / f"IMG_{i:03d}.jpg"), 255 - frame)
        cv2.imwrite(str(root / "rgb" / f"IMG_{i:03d}.JPG"), np.dstack([frame] * 3))
        if i in missing:
            continue
        if fmt == "npy":
            np.save(
                root / "warped_thermal" / f"IMG_{i:03d}.npy", (16.8 + frame * (48.3 - 16.8) / 255).astype(np.float32)
            )
        else:
            cv2.imwrite(str(root / "warped_thermal" / f"IMG_{i:03d}.jpg"), frame)
    poses = cameras(n)
    write_colmap_model(root / "colmap_sparse" / "0", names, poses, K, (80, 60))
    return [(c2w, K) for i, (c2w, _) in enumerate(zip(poses, names)) if i not in missing]


def write_colmap(
    root: Path, n: int = 17, binary: bool = True, with_point: bool = True, extra_points: int = 0
) -> List[Tuple[np.ndarray, np.ndarray]]:
    K = _K(60.0, 61.0, 31.5, 24.5)
    (root / "images").mkdir(parents=True)
    names = [f"frame_{i}.png" for i in range(n)]  # natural order: frame_2 before frame_10
    for i, name in enumerate(names):
        cv2.imwrite(str(root / "images" / name), thermal_image(64, 48, i))
    poses = cameras(n)
    write_colmap_model(
        root / "sparse" / "0",
        names,
        poses,
        K,
        (64, 48),
        binary=binary,
        with_point=with_point,
        extra_points=extra_points,
    )
    return [(c2w, K) for c2w in poses]


def write_ti_nsd(root: Path, n: int = 20) -> List[Tuple[np.ndarray, np.ndarray]]:
    """TI-NSD (Thermal3D-GS) as released: `images/` with numeric, unpadded names (1.jpg ... n.jpg,
    8-bit grey), `sparse/0` binary, PINHOLE. Returns (c2w, K) in capture order (1, 2, ...)."""
    K = _K(60.0, 60.0, 32.0, 24.0)
    (root / "images").mkdir(parents=True)
    names = [f"{i + 1}.jpg" for i in range(n)]
    for i, name in enumerate(names):
        cv2.imwrite(str(root / "images" / name), thermal_image(64, 48, i, np.uint8))
    poses = cameras(n)
    write_colmap_model(root / "sparse" / "0", names, poses, K, (64, 48))
    return [(c2w, K) for c2w in poses]


ODM_LLA = {"latitude": 46.4, "longitude": 6.24, "altitude": 400.0}
"""The OpenDroneMap fixture's reference point (near flight2's site)."""


def write_odm(
    root: Path, n: int = 10, files: Optional[List[Path]] = None, size: Tuple[int, int] = (64, 48)
) -> List[Tuple[np.ndarray, np.ndarray]]:
    """An OpenDroneMap project: images/DJI_00NN.png and opensfm/reconstruction.json (OpenSfM's
    normalised brown cameras, world-to-camera axis-angle poses, points) + opensfm/reference_lla.json.
    `files`: real frames copied in as images/DJI_00NN_T.jpg instead (`size` theirs, one shot each)."""
    width, height = size
    n = n if files is None else len(files)
    K = _K(60.0 * width / 64, 61.0 * width / 64, width / 2 + 1.0, height / 2 - 0.5)
    (root / "images").mkdir(parents=True)
    (root / "opensfm").mkdir()
    poses = cameras(n)
    size = max(width, height)
    camera = {
        "projection_type": "brown",
        "width": width,
        "height": height,
        "focal_x": K[0, 0] / size,
        "focal_y": K[1, 1] / size,
        "c_x": (K[0, 2] - width / 2) / size,
        "c_y": (K[1, 2] - height / 2) / size,
        **{k: 0.0 for k in ("k1", "k2", "k3", "p1", "p2")},
    }
    shots = {}
    for i, c2w in enumerate(poses):
        if files is None:
            name = f"DJI_{i + 1:04d}.png"
            cv2.imwrite(str(root / "images" / name), thermal_image(width, height, i))
        else:
            name = f"DJI_{i + 1:04d}_T.jpg"
            shutil.copyfile(files[i], root / "images" / name)
        w2c = np.linalg.inv(c2w)
        shots[name] = {
            "camera": "v2 thermal",
            "rotation": cv2.Rodrigues(w2c[:3, :3])[0].ravel().tolist(),
            "translation": w2c[:3, 3].tolist(),
        }
    points = {str(k): {"coordinates": (KNOWN_POINT + 0.05 * k).tolist(), "color": [200, 200, 200]} for k in range(40)}
    reconstruction = [{"cameras": {"v2 thermal": camera}, "shots": shots, "points": points}]
    (root / "opensfm" / "reconstruction.json").write_text(json.dumps(reconstruction))
    (root / "opensfm" / "reference_lla.json").write_text(json.dumps(ODM_LLA))
    return [(c2w, K) for c2w in poses]
