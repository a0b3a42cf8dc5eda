//! Area lights in Whitted mode (placeholder while the pin is computed).

#[cfg(test)]
mod pin;
#[cfg(test)]
mod tests;
