from rosdeploy.suggest import closest, did_you_mean


def test_a_transposed_letter_is_suggested():
    assert closest("ros_domian_id", ["ros_domain_id", "ros_network"]) == "ros_domain_id"
    assert did_you_mean("rosdeploy_deploy_rot", ["rosdeploy_deploy_root"]) == "did you mean 'rosdeploy_deploy_root'?"


def test_an_unrelated_word_gets_no_suggestion():
    assert closest("gpu", ["ros_domain_id", "devices"]) is None
    assert did_you_mean("zzz", ["ros_domain_id"]) == ""
