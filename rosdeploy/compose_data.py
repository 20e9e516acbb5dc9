"""What the built-in templates/compose.yml.j2 renders, as data: the checks read this instead
of parsing every robot's compose.yml back.

Parsing 5,000 rendered compose files took 40 of the 52 s `check` spent on 5,000 robots
(issue 18). The built-in template's output is a pure function of the same context, so
`compose_data(context)` builds the parsed form directly; a user's own compose.yml.j2 is
still parsed back (checks.parse_release). tests/unit/test_compose_data.py holds the two
equal (yaml.safe_load(rendered) == compose_data(...)) over every fleet the tests render,
so this mirror cannot drift from the template unnoticed.
"""
from __future__ import annotations

from typing import Any, Mapping

from rosdeploy.compose_env import interpolate


class _Raw:
    """The file as written: literals with `$$`, .env references as `${NAME:?...}`."""

    @staticmethod
    def lit(value: Any) -> str:
        return str(value).replace("$", "$$")   # compose_str

    def ref(self, name: str) -> str:
        return f"${{{name}:?{name} must be set in .env}}"   # env_ref

    def extra(self, svc: Any) -> Mapping[str, Any]:
        return svc.extra


class _Resolved(_Raw):
    """The file as compose reads it, interpolated with the robot's .env (compose_env.interpolate's result)."""

    def __init__(self, env: Mapping[str, str]) -> None:
        self.env = env

    @staticmethod
    def lit(value: Any) -> str:
        return str(value)                       # `$$` reads back as `$`

    def ref(self, name: str) -> str:
        return self.env.get(name) or ""

    def extra(self, svc: Any) -> Mapping[str, Any]:
        return interpolate(svc.extra, self.env)


def compose_data(ctx: Mapping[str, Any], env: Mapping[str, str] | None = None) -> dict[str, Any]:
    """The parsed form of compose.yml.j2 rendered with `ctx` (Renderer._context); with `env` (the
    robot's .env), that form interpolated the way compose reads it."""
    mode = _Raw() if env is None else _Resolved(env)
    _lit, _ref = mode.lit, mode.ref
    env = {"ROS_DOMAIN_ID": _ref("ROS_DOMAIN_ID"), "RMW_IMPLEMENTATION": _ref("RMW_IMPLEMENTATION"),
           **{key: _lit(value) for key, value in ctx["dds_env"]}, "ROS_LOG_DIR": "/ros_log"}
    common: dict[str, Any] = {"environment": env}
    if ctx["network_mode"] == "host":
        common["network_mode"] = "host"
    else:
        common["networks"] = ["ros"]
    common["shm_size"] = _lit(ctx["shm_size"])
    common["logging"] = {"driver": "json-file", "options": {"max-size": _lit(ctx["log_max_size"]),
                                                            "max-file": _lit(ctx["log_max_file"])}}
    out: dict[str, Any] = {"x-ros-common": common,
                           "services": {svc.name: _service(svc, ctx, common, mode) for svc in ctx["services"]}}
    if ctx["network_mode"] == "bridge":
        out["networks"] = {"ros": {"driver": "bridge"}}
    return out


def _service(svc: Any, ctx: Mapping[str, Any], common: Mapping[str, Any], mode: _Raw) -> dict[str, Any]:
    dds, _lit, _ref = ctx["dds_file"], mode.lit, mode.ref
    out: dict[str, Any] = {**common, "image": _lit(svc.image)}
    if svc.command is not None:
        out["command"] = [_lit(w) for w in svc.command]
    out["environment"] = {**common["environment"], **{k: _lit(v) for k, v in svc.environment},
                          **{k: _ref(k) for k in svc.secrets}}
    out["volumes"] = [_lit(f"{ctx['dds_source']}:/{dds}:ro"), "/dev/shm:/dev/shm", _lit(f"{svc.log_dir}:/ros_log"),
                      *(_lit(v) for v in svc.volumes), *(_lit(m) for m in svc.mounts)]
    if svc.shm_size != ctx["shm_size"]:
        out["shm_size"] = _lit(svc.shm_size)
    out["restart"] = _lit(svc.restart)
    if svc.mem_limit:
        out["mem_limit"] = _lit(svc.mem_limit)
    if svc.cpus is not None:
        out["cpus"] = float(svc.cpus)
    if svc.healthcheck:
        hc = svc.healthcheck
        out["healthcheck"] = {"test": [_lit(w) for w in hc.test], "interval": _lit(hc.interval),
                              "timeout": _lit(hc.timeout), "retries": int(hc.retries),
                              "start_period": _lit(hc.start_period)}
    if svc.depends_on:
        out["depends_on"] = {dep: {"condition": "service_healthy"} for dep in svc.depends_on}
    for key, values in (("devices", svc.devices), ("group_add", svc.group_add)):
        if values:
            out[key] = [_lit(v) for v in values]
    if svc.user:
        out["user"] = _lit(svc.user)
    if svc.privileged:
        out["privileged"] = True
    if svc.profiles:
        out["profiles"] = [_lit(p) for p in svc.profiles]
    if svc.gpu:
        # The runtime preflight checks for, with NVIDIA_VISIBLE_DEVICES (render.GPU_ENV): what Compose
        # v1 and v2 both write the same way. A `deploy.resources.reservations` device request needs
        # dockerd's nvidia device driver as well (nvidia-container-runtime-hook at dockerd start),
        # which a robot can lack while its `nvidia` runtime is present.
        out["runtime"] = "nvidia"
    out["labels"] = {key: _lit(value) for key, value in svc.labels}
    out.update(mode.extra(svc))
    return out
