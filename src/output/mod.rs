//! Write: one .glb per chunk ([`gltf`], vertex data compressed by
//! [`compress`] when asked) and the 3D Tiles index ([`tileset`]),
//! into a temporary directory that is renamed into place only when complete.

pub mod compress;
pub mod glb;
pub mod gltf;
pub mod tileset;
