"""Where the package's configuration files are: the installed share/ first, else the source
tree."""
import pathlib

PACKAGE_NAME = "softgrip_ros"


def config_dir() -> pathlib.Path:
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
    except ImportError:  # plain Python, no ROS: the source checkout
        return _source_config_dir()
    try:
        return pathlib.Path(get_package_share_directory(PACKAGE_NAME)) / "config"
    except (PackageNotFoundError, ValueError, LookupError):
        return _source_config_dir()


def _source_config_dir() -> pathlib.Path:
    return pathlib.Path(__file__).resolve().parents[2] / "config"


def config_file(name: str) -> pathlib.Path:
    path = config_dir() / name
    if not path.is_file():
        raise FileNotFoundError(
            f"{name} not found in {path.parent} (is softgrip_ros built and sourced?)")
    return path
