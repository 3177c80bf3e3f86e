"""Launch the train_calib node graph (full ROS 2 installs): ros2 launch train_calib train_calib.launch.py

Arguments (``name:=value``):
  params_file    ROS 2 params file for every node (default: the package's config/train_calib.yaml)
  track          track file or bundled track name (overrides track_file of the params file)
  train          train file or bundled train name (overrides train_file)
  use_sim_time   true when a bag is played with --clock (default false)
  traction_power true when the train publishes /train/traction_power: starts window_calib_node (default false)
  window         auto (default: as traction_power says), true or false: start window_calib_node or not
  ukf_preset     learning (default: the params file's values, r learnt from the run's coasting), paper (adds
                 config/ukf_paper.yaml: Table 1) or converging (adds config/ukf_converging.yaml), for ukf_node,
                 after params_file
  namespace      namespace of the nodes (default none)
  prediction     true: also start prediction_node (/train_calib/prediction, docs/prediction.md; default false)

``describe()`` gives the same graph as plain data without importing ``launch`` (used by the tests).
"""

from __future__ import annotations

from pathlib import Path

PACKAGE = "train_calib"
GRAPH = ("gnss_speed_node", "ukf_node", "regime_node", "feature_node")
OPTIONAL = ("window_calib_node",)
PREDICTION = ("prediction_node",)
FILE_PARAMETERS = {
    "gnss_speed_node": ("track_file", "train_file"),
    "ukf_node": ("train_file",),
    "regime_node": ("train_file",),
    "window_calib_node": ("train_file",),
    "prediction_node": ("track_file", "train_file"),
}
ARGUMENTS = {
    "params_file": ("", "ROS 2 params file for every node (empty: the package's config/train_calib.yaml)"),
    "track": ("", "track file or bundled track name (empty: track_file of the params file)"),
    "train": ("", "train file or bundled train name (empty: train_file of the params file)"),
    "use_sim_time": ("false", "use /clock (bag playback with --clock)"),
    "traction_power": ("false", "the train publishes /train/traction_power: start window_calib_node"),
    "window": ("auto", "start window_calib_node: auto (when traction_power is true), true or false"),
    "ukf_preset": (
        "learning",
        "ukf_node preset: learning (the params file), paper (ukf_paper.yaml: Table 1) or converging "
        "(ukf_converging.yaml)",
    ),
    "namespace": ("", "namespace of the nodes"),
    "prediction": ("false", "start prediction_node (/train_calib/prediction)"),
}
UKF_PRESETS = ("learning", "paper", "converging")
TRUE = ("true", "1", "yes", "on")
FALSE = ("false", "0", "no", "off")


def config_file(name: str) -> str:
    """The installed config/<name>, else the source tree's."""
    try:
        from ament_index_python.packages import get_package_share_directory

        candidate = Path(get_package_share_directory(PACKAGE)) / "config" / name
        if candidate.is_file():
            return str(candidate)
    except Exception:
        pass
    return str(Path(__file__).resolve().parent.parent / "config" / name)


def default_params_file() -> str:
    """The installed config/train_calib.yaml, else the source tree's."""
    return config_file("train_calib.yaml")


def flag(name: str, text: str | bool, allow_auto: bool = False) -> bool | None:
    """A launch argument's boolean (None for auto); ValueError naming the argument otherwise."""
    if isinstance(text, bool):
        return text
    value = str(text).strip().lower()
    if value in TRUE:
        return True
    if value in FALSE:
        return False
    if allow_auto and value == "auto":
        return None
    choices = "true, false" + (", auto" if allow_auto else "")
    raise ValueError(f"launch argument {name}: {text!r} is not one of {choices}")


def describe(
    params_file: str = "",
    track: str = "",
    train: str = "",
    use_sim_time: bool | str = False,
    window: bool | str | None = None,
    namespace: str = "",
    traction_power: bool | str = False,
    ukf_preset: str = "learning",
    prediction: bool | str = False,
) -> list[dict]:
    """The nodes to start, as plain data: package, executable, name, namespace, parameters (files in order,
    then the overrides). window None / "auto": window_calib_node when traction_power is true."""
    run_window = flag("window", window, allow_auto=True) if window is not None else None
    if run_window is None:
        run_window = flag("traction_power", traction_power)
    if ukf_preset not in UKF_PRESETS:
        raise ValueError(f"launch argument ukf_preset: {ukf_preset!r} is not one of {', '.join(UKF_PRESETS)}")
    nodes = []
    for name in GRAPH + (OPTIONAL if run_window else ()) + (PREDICTION if flag("prediction", prediction) else ()):
        overrides: dict = {"use_sim_time": flag("use_sim_time", use_sim_time)}
        for key in FILE_PARAMETERS.get(name, ()):
            value = track if key == "track_file" else train
            if value:
                overrides[key] = value
        files = [params_file or default_params_file()]
        if name == "ukf_node" and ukf_preset != "learning":
            files.append(config_file(f"ukf_{ukf_preset}.yaml"))
        nodes.append(
            {
                "package": PACKAGE,
                "executable": name,
                "name": name,
                "namespace": namespace,
                "parameters": [*files, overrides],
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
        use_sim_time=arg("use_sim_time"),
        window=arg("window"),
        namespace=arg("namespace"),
        traction_power=arg("traction_power"),
        ukf_preset=arg("ukf_preset"),
        prediction=arg("prediction"),
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
