"""The simulated platform with true parameter errors, its feed sensors and a laser tracker
(SEEDS_CDE.md section 004, proposed values). Truth is for tests, benches and sim nodes."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from platform_calib.core.geometry import PlatformGeometry, nominal_geometry
from platform_calib.core.identification import PoseData
from platform_calib.core.kinematics import check_stroke, forward, inverse

TRACKER_NOISE = (10e-6, 10e-6, 20e-6)      # x m, y m, theta rad, 1 sigma
FEED_SENSOR_NOISE = 1e-6                   # m, 1 sigma


def true_geometry(seed: int = 0, scale: float = 1.0,
                  nominal: PlatformGeometry | None = None) -> PlatformGeometry:
    """The nominal platform with every length off by 0.2-1 mm and every feed direction by
    up to 0.5 degree (random signs), all times ``scale``."""
    nominal = nominal or nominal_geometry()
    rng = np.random.default_rng(seed)
    v = nominal.vector().reshape(3, 6)
    lengths = rng.uniform(0.2e-3, 1e-3, (3, 5)) * rng.choice([-1, 1], (3, 5))
    v[:, [0, 1, 3, 4, 5]] += scale * lengths
    v[:, 2] += scale * np.deg2rad(rng.uniform(-0.5, 0.5, 3))
    return nominal.with_vector(v.ravel())


@dataclass
class PlatformSim:
    """The platform at its current feeds. ``move`` refuses feeds outside the stroke (the
    platform stays); ``pose`` is truth; ``read_feeds`` and ``track`` are the sensors.

    Effects the 18-parameter model lacks, off by default: each ball screw's periodic error
    (``screw_amplitude`` (3,) m, once per ``lead`` m of feed) and ``backlash`` (3,) m (the
    slide lags the drive by half of it against the last direction of motion), and each
    feed's true lead over its nominal (``feed_scale`` (3,): the slide travels that many
    times the feed read). The drive reports the commanded feed; the slide is where these
    put it."""

    geometry: PlatformGeometry
    seed: int = 0
    feed_noise: float = FEED_SENSOR_NOISE
    tracker_noise: tuple = TRACKER_NOISE
    screw_amplitude: tuple = (0.0, 0.0, 0.0)
    backlash: tuple = (0.0, 0.0, 0.0)
    lead: float = 5e-3
    feed_scale: tuple = (1.0, 1.0, 1.0)

    def __post_init__(self):
        self.feeds = inverse(self.geometry, np.zeros(3))[0]
        self.pose = np.zeros(3)
        self.direction = np.ones(3)
        self.rng = np.random.default_rng(self.seed)
        self.phase = self.rng.uniform(0, 2 * np.pi, 3)

    def slides(self, feeds, direction) -> np.ndarray:
        """Where the slides are for commanded ``feeds`` (3,) (m) last moved in
        ``direction`` (3,)."""
        return (feeds * np.asarray(self.feed_scale) + np.asarray(self.screw_amplitude)
                * np.sin(2 * np.pi * feeds / self.lead + self.phase)
                - np.asarray(self.backlash) / 2 * direction)

    def move(self, feeds) -> np.ndarray:
        """Drive the feeds to ``feeds`` (3,) m; the pose they give (truth)."""
        feeds = check_stroke(self.geometry, feeds)[0]
        moving = feeds != self.feeds
        direction = np.where(moving, np.sign(feeds - self.feeds), self.direction)
        # The state changes only once the pose is known: a refused move leaves it as it was.
        self.pose = forward(self.geometry, self.slides(feeds, direction)[None], self.pose[None])[0]
        self.feeds, self.direction = feeds, direction
        return self.pose

    def read_feeds(self) -> np.ndarray:
        return self.feeds + self.rng.normal(0.0, self.feed_noise, 3)

    def track(self) -> np.ndarray:
        return self.pose + self.rng.normal(0.0, self.tracker_noise, 3)


def plan_poses(count: int, seed: int = 0, span=(5e-3, 5e-3, np.deg2rad(5.0))) -> np.ndarray:
    """``count`` random poses within +-``span`` (x m, y m, theta rad)."""
    rng = np.random.default_rng(seed + 77)
    return rng.uniform(-1, 1, (count, 3)) * np.asarray(span)


def measure_poses(sim: PlatformSim, targets: np.ndarray, nominal: PlatformGeometry) -> PoseData:
    """Command each target through the nominal inverse kinematics, then read the feed
    sensors and the tracker (the identification's data, with each feed's direction of
    approach)."""
    feeds, poses, directions = [], [], []
    for target in targets:
        sim.move(inverse(nominal, target[None])[0])
        feeds.append(sim.read_feeds())
        poses.append(sim.track())
        directions.append(sim.direction.copy())
    return PoseData(np.array(poses), np.array(feeds), {'direction': np.array(directions)})
