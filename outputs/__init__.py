"""The outputs a frame writes: the output table, its encoders and PNG deflaters, the objects sidecar, camera geometry. Below the manifest: imports only domains and storage of ours."""
