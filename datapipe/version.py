"""DataPipe's version, in a leaf module: the run loop records it in run.json without importing the
package's face (datapipe/__init__.py, which reaches the add-on and the API). Kept equal to
blender_manifest.toml's and pyproject.toml's (make/build_extension.py checks the manifest)."""
__version__ = "0.1.0"
