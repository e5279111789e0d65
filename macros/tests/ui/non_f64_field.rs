use hinge_core::HingeEnergy;

#[derive(HingeEnergy)]
#[psi(k * (theta - theta_bar).powi(2))]
pub struct Bad {
    pub k: f32,
    pub name: String,
}

fn main() {}
