use hinge_core::HingeEnergy;

#[derive(HingeEnergy)]
#[psi(k * (theta - theta_bar).abs())]
pub struct Bad {
    pub k: f64,
}

fn main() {}
