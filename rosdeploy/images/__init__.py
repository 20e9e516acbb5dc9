"""Images for robots: pinned by digest, by the registry or over rosdeploy's SSH link, rate-capped,
from a registry or a bundle (docs/images.md).

    refs.py      names, pins, rates          registry.py  the controller's registry client
    supply.py    one run's pins and routes   forward.py   the reverse port forward and its pacing
    pull.py      one robot's pull step       bundle.py    air-gapped bundles and their server
"""
