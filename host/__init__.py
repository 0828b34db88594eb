"""Host-side tools: what an export machine or a workstation needs and a phone or Jetson does not.

The device path (`import mosaicthinker.runtime`, `load_bundle`, `ask`, `build_map`, `mosaic ask|map`) never
imports this package (tests/test_device_path.py proves it). Here:

- `bundle_write`: writing bundles (manifest creation, roles and variants, I/O specs read from the graphs);
  the schema and its checks stay in `runtime/infra/bundle.py`, which the device reads.
- `report`: the `mosaic profile --out` report files (Markdown, PNG charts).
"""
