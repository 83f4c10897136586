"""The viewer's layout (a Rerun blueprint), stored in every file so that it opens ready to read."""

from __future__ import annotations

import rerun.blueprint as rrb


def env_layout(i: int) -> rrb.Horizontal:
    """Env i: the wrist camera (rgb, segmentation, boxes, mask) above the target image; a 3D view (camera
    frustum, end-effector path, objects); plots of reward, target fraction and success with the text log."""
    return rrb.Horizontal(
        rrb.Vertical(
            rrb.Spatial2DView(name=f"env{i} wrist camera", origin=f"world/env{i}/camera/image"),
            rrb.Spatial2DView(name=f"env{i} target image", origin=f"env{i}/target_image"),
            row_shares=[3, 2],
        ),
        rrb.Spatial3DView(name=f"env{i} 3D", origin=f"world/env{i}"),
        rrb.Vertical(
            rrb.TimeSeriesView(
                name="reward and target fraction",
                origin=f"env{i}",
                contents=[f"env{i}/reward", f"env{i}/target_fraction"],
            ),
            rrb.TimeSeriesView(name="success", origin=f"env{i}", contents=[f"env{i}/success"]),
            rrb.TextLogView(name="actions and outcomes", origin=f"env{i}"),
        ),
        column_shares=[2, 3, 2],
        name=f"env{i}",
    )


def blueprint(num_envs: int = 1) -> rrb.Blueprint:
    """The whole layout: one env's, or one tab per env when there are several."""
    layout = env_layout(0) if num_envs == 1 else rrb.Tabs(*[env_layout(i) for i in range(num_envs)])
    return rrb.Blueprint(layout, rrb.TimePanel(timeline="step"), collapse_panels=True)
