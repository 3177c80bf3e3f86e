"""Launch the train_calib node graph (full ROS 2 installs): ros2 launch train_calib train_calib.launch.py

Arguments (``name:=value``):
  params_file    ROS 2 params file for every node (default: the package's config/train_calib.yaml)
  track          track file or bundled track name (overrides track_file of the params file)
  train          train file or bundled train name (overrides train_file)
  use_sim_time   true when a bag is played with --clock (default false)
  window         true to also start window_calib_node (needs /train/traction_power)
  namespace      namespace of the nodes (default none)

``describe()`` gives the same graph as plain data without importing ``launch`` (used by the tests).
"""

from __future__ import annotations

from pathlib import Path

PACKAGE = "train_calib"
GRAPH = ("gnss_speed_node", "ukf_node", "regime_node", "feature_node")
OPTIONAL = ("window_calib_node",)
FILE_PARAMETERS = {
    "gnss_speed_node": ("track_file", "train_file"),
    "ukf_node": ("train_file",),
    "window_calib_node": ("train_file",),
}
ARGUMENTS = {
    "params_file": ("", "ROS 2 params file for every node (empty: the package's config/train_calib.yaml)"),
    "track": ("", "track file or bundled track name (empty: track_file of the params file)"),
    "train": ("", "train file or bundled train name (empty: train_file of the params file)"),
    "use_sim_time": ("false", "use /clock (bag playback with --clock)"),
    "window": ("false", "also start window_calib_node (needs traction power)"),
    "namespace": ("", "namespace of the nodes"),
}


def default_params_file() -> str:
    """The installed config/train_calib.yaml, else the source tree's."""
    try:
        from ament_index_python.packages import get_package_share_directory

        candidate = Path(get_package_share_directory(PACKAGE)) / "config" / "train_calib.yaml"
        if candidate.is_file():
            return str(candidate)
    except Exception:
        pass
    return str(Path(__file__).resolve().parent.parent / "config" / "train_calib.yaml")


def describe(
    params_file: str = "",
    track: str = "",
    train: str = "",
    use_sim_time: bool = False,
    window: bool = False,
    namespace: str = "",
) -> list[dict]:
    """The nodes to start, as plain data: package, executable, name, namespace, parameters."""
    nodes = []
    for name in GRAPH + (OPTIONAL if window else ()):
        overrides: dict = {"use_sim_time": bool(use_sim_time)}
        for key in FILE_PARAMETERS.get(name, ()):
            value = track if key == "track_file" else train
            if value:
                overrides[key] = value
        nodes.append(
            {
                "package": PACKAGE,
                "executable": name,
                "name": name,
                "namespace": namespace,
                "parameters": [params_file or default_params_file(), overrides],
            }
        )
    return nodes


def _nodes(context):
    from launch.substitutions import LaunchConfiguration
    from launch_ros.actions import Node

    def arg(name: str) -> str:
        return context.perform_substitution(LaunchConfiguration(name))

    described = describe(
        params_file=arg("params_file"),
        track=arg("track"),
        train=arg("train"),
        use_sim_time=arg("use_sim_time").lower() in ("true", "1", "yes"),
        window=arg("window").lower() in ("true", "1", "yes"),
        namespace=arg("namespace"),
    )
    return [
        Node(
            package=d["package"],
            executable=d["executable"],
            name=d["name"],
            namespace=d["namespace"],
            parameters=d["parameters"],
            output="screen",
            emulate_tty=True,
        )
        for d in described
    ]


def generate_launch_description():
    from launch.actions import DeclareLaunchArgument, OpaqueFunction

    from launch import LaunchDescription

    return LaunchDescription(
        [
            DeclareLaunchArgument(name, default_value=default, description=doc)
            for name, (default, doc) in ARGUMENTS.items()
        ]
        + [OpaqueFunction(function=_nodes)]
    )
