//! Finite elements of the free-motion stage (paper §III-B, eq. 1): corotational linear
//! tetrahedra for the gel ([`tetra`]) and corotational 3-D beams for the needle ([`beam`]).

pub mod beam;
mod hyperdual;
pub mod tetra;
