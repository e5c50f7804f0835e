"""Reading and writing files: meshes (read.py, write.py, gltf.py), tet meshes, runtime files."""
