//! Write: one .glb per chunk ([`gltf`]) and the 3D Tiles index ([`tileset`]),
//! into a temporary directory that is renamed into place only when complete.

pub mod gltf;
pub mod tileset;
