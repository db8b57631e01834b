"""The ``robodk`` motion adapter: linear moves through the RoboDK API (robodk package, 6.x).

The workplane frame is a RoboDK reference frame (``frame_name``, corrected by the tilt that a
run reports); targets are poses in it with the tool orientation ``orientation_deg``. With
``run_on_robot`` the station drives the real robot (RUNMODE_RUN_ROBOT through its driver);
otherwise RoboDK only simulates the moves.
Not tested against the RoboDK app (it cannot be installed here): see docs/adapters/robodk.md.
"""
from __future__ import annotations

from .base import AdapterError
from .schema import RobodkConfig


class RobodkMotion:
    """Motion protocol over the RoboDK API."""

    def __init__(self, cfg: RobodkConfig):
        from robodk import robolink, robomath

        self.cfg, self.rm, self.rl = cfg, robomath, robolink
        self.where = f"robot.robodk {cfg.host}:{cfg.port}"
        # an IP, never 'localhost': a failed connect must not try to launch the RoboDK app
        host = "127.0.0.1" if cfg.host == "localhost" else cfg.host
        try:
            self.rdk = robolink.Robolink(robodk_ip=host, port=cfg.port, close_std_out=True)
        except Exception as e:
            raise AdapterError(f"{self.where}: cannot connect ({e}); start RoboDK and its API") from e
        if self.rdk.PORT == -1 or not getattr(self.rdk, "COM", None):
            raise AdapterError(f"{self.where}: RoboDK is not answering; start RoboDK with the "
                               "API enabled (Tools > Options > Other > RoboDK API)")
        try:
            self.robot = self.rdk.Item(cfg.robot_name, robolink.ITEM_TYPE_ROBOT)
            if not self.robot.Valid():
                raise AdapterError(f"{self.where}: no robot named {cfg.robot_name!r} in the station"
                                   " (robot.robodk.robot_name)")
            if cfg.frame_name:
                frame = self.rdk.Item(cfg.frame_name, robolink.ITEM_TYPE_FRAME)
                if not frame.Valid():
                    raise AdapterError(f"{self.where}: no frame named {cfg.frame_name!r} "
                                       "(robot.robodk.frame_name)")
                self.robot.setPoseFrame(frame)
            self.rdk.setRunMode(robolink.RUNMODE_RUN_ROBOT if cfg.run_on_robot
                                else robolink.RUNMODE_SIMULATE)
            if cfg.run_on_robot:
                self.robot.Connect()
            self.robot.setSpeed(cfg.speed_mm_per_s)
        except AdapterError:
            raise
        except Exception as e:
            raise AdapterError(f"{self.where}: setting up the station failed: {e}") from e

    def _pose(self, x, y, z):
        rx, ry, rz = self.cfg.orientation_deg
        return self.rm.transl(x, y, z) * self.rm.rotz(self.rm.pi / 180 * rz) \
            * self.rm.roty(self.rm.pi / 180 * ry) * self.rm.rotx(self.rm.pi / 180 * rx)

    def move_to(self, x_mm: float, y_mm: float, z_mm: float) -> None:
        try:
            self.robot.MoveL(self._pose(x_mm, y_mm, z_mm))
        except self.rl.TargetReachError as e:
            raise AdapterError(f"{self.where}: target ({x_mm:.3f}, {y_mm:.3f}, {z_mm:.3f}) "
                               f"cannot be reached: {e}; check the frame and the orientation")
        except self.rl.StoppedError as e:
            raise AdapterError(f"{self.where}: the move was stopped: {e}; continue with --resume")
        except Exception as e:
            raise AdapterError(f"{self.where}: move failed: {e}") from e

    def position(self) -> tuple[float, float, float]:
        try:
            p = self.robot.Pose().Pos()
        except Exception as e:
            raise AdapterError(f"{self.where}: reading the pose failed: {e}") from e
        return float(p[0]), float(p[1]), float(p[2])

    def close(self) -> None:
        try:
            self.rdk.Disconnect()
        except Exception:  # already gone; nothing left to release
            pass
