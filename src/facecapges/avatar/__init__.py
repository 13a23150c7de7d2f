"""The avatar: blendshapes by AOI Laplacian deformation, a skinned BEAT body, glTF, rendering."""
