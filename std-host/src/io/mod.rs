//! Files in and out: the checkout's default files ([`checkout`]), safe reads and atomic
//! writes ([`files`]), views as 8-bit gray
//! ([`image_io`]), PFM ([`pfm`]), `.npy` / `.npz` arrays ([`npy`], [`npz`]), false-colour
//! pictures ([`colour`]), JSON objects in their keys' order (`keyed`) and the project's Python
//! environment, which some commands run ([`train_python`]).

pub mod checkout;
pub mod colour;
pub mod colour_bar;
pub mod files;
pub mod image_io;
pub(crate) mod keyed;
pub mod npy;
pub mod npz;
pub mod pfm;
pub mod train_python;
