#!/usr/bin/env python3
"""A helm post-renderer for the test bed: the bundled store's pod without its HTTP probes.

The test bed's pod network is a bridge with no address on the host, so the kubelet cannot
reach a pod's IP to probe it (tests/images/test_helm_store_pod.py). Everything else of the
rendered chart passes through unchanged. Reads the manifests on stdin, writes them on stdout.
"""

from __future__ import annotations

import sys

import yaml


def main() -> None:
    documents = [doc for doc in yaml.safe_load_all(sys.stdin) if doc]
    for doc in documents:
        if doc.get("kind") == "StatefulSet" and doc["metadata"]["name"].endswith("-store"):
            for container in doc["spec"]["template"]["spec"]["containers"]:
                container.pop("readinessProbe", None)
                container.pop("livenessProbe", None)
    yaml.safe_dump_all(documents, sys.stdout)


if __name__ == "__main__":
    main()
