"""The kubelet device-plugin API for this host's cells (docs/agent.md, "Devices").

``decide`` holds the pure decisions (resource name, health, allocation),
``server`` the gRPC servers and their registration with the kubelet, and
``v1beta1`` the stubs generated from the kubelet's ``api.proto``
(``scripts/dev/gen-deviceplugin-stubs.sh``).
"""
