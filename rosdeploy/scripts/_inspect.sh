# shellcheck shell=sh
# shellcheck disable=SC2034 # fmt is for the script's `docker inspect`
# What the health gate reads of a container: one line of JSON per container.

fmt='{"id":{{json .Id}},"name":{{json .Name}},'\
'"service":{{json (index .Config.Labels "com.docker.compose.service")}},"image":{{json .Config.Image}},'\
'"status":{{json .State.Status}},"health":{{if .State.Health}}{{json .State.Health.Status}}{{else}}null{{end}},'\
'"restarts":{{.RestartCount}},"started":{{json .State.StartedAt}},'\
'"workdir":{{json (index .Config.Labels "com.docker.compose.project.working_dir")}},'\
'"test":{{if .Config.Healthcheck}}{{json .Config.Healthcheck.Test}},'\
'"test_timeout":{{json .Config.Healthcheck.Timeout}}{{else}}null{{end}}}'
