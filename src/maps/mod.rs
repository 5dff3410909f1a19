//! What a base carries out to other tools: the atlas and fold image ([`fold`]), the
//! displacement map baked over it ([`bake`]), the `BASE.map` records ([`mapfile`]), the binary
//! glTF ([`export`]), reconstruction and its distances ([`reconstruct`]) and their chart ([`plot`]).

pub mod bake;
pub mod export;
pub mod fold;
pub mod mapfile;
pub mod plot;
pub mod reconstruct;
